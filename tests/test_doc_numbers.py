"""The numbers the docs quote from committed results files equal what the files hold (tools/check_doc_numbers.py):
each such number carries its source as an HTML comment, and a page that says otherwise fails here."""
import json

from tools_import import _load

check_doc_numbers = _load("check_doc_numbers")


def test_every_quoted_number_on_the_pages_matches_its_file():
    total, failures = 0, []
    for page in check_doc_numbers.pages():
        checked, failed = check_doc_numbers.check_page(page)
        total += checked
        failures += failed
    assert not failures, "\n".join(failures)
    assert total >= 20


def quoted(tmp_path, text, content):
    (tmp_path / "results.json").write_text(json.dumps(content))
    page = tmp_path / "page.md"
    page.write_text(text)
    return check_doc_numbers.check_page(page, root=tmp_path)


def test_a_page_that_differs_from_its_file_fails_with_one_line_naming_both(tmp_path):
    runs = {"runs": [{"model": "D", "p95": p95} for p95 in (1.8, 2.06, 1.86, 1.86, 2.18)]}
    source = '<!-- = results.json: sum(run["p95"] < 2 for run in r["runs"] if run["model"] == "D") -->'
    assert quoted(tmp_path, f"on the edge (3{source} of 5 plans below 2 ms)", runs) == (1, [])
    checked, failures = quoted(tmp_path, f"on the edge (4{source} of 5 plans below 2 ms)", runs)
    assert checked == 1 and failures == ["page.md:1: the page says 4; results.json gives 3"]


def test_digits_written_set_the_tolerance_and_ranges_take_two_numbers(tmp_path):
    content = {"seconds": 590.3, "ratio": 1.0972, "values": [0.1749, 0.4978], "small": 1.72e-8}
    assert quoted(tmp_path, '590 s<!-- = results.json: r["seconds"] -->, 1.097x<!-- = results.json: r["ratio"] -->, '
                  '0.17-0.50<!-- = results.json: (min(r["values"]), max(r["values"])) -->, 1.7e-8 rad²<!-- = '
                  'results.json: r["small"] -->', content) == (4, [])
    assert quoted(tmp_path, '668 s<!-- = results.json: r["seconds"] -->', content)[1]
    assert quoted(tmp_path, '1.09x<!-- = results.json: r["ratio"] -->', content)[1]   # (1.10 would round it right)
    assert quoted(tmp_path, '0.17-0.51<!-- = results.json: (min(r["values"]), max(r["values"])) -->', content)[1]


def test_a_missing_file_or_key_is_a_failure_not_a_pass(tmp_path):
    assert "not a committed results file" in quoted(tmp_path, '3<!-- = nothing.json: r["x"] -->', {})[1][0]
    assert "KeyError" in quoted(tmp_path, '3<!-- = results.json: r["x"] -->', {})[1][0]
    assert "expected" in quoted(tmp_path, 'none<!-- = results.json: r["x"] -->', {"x": 3})[1][0]


def test_the_number_stands_right_before_its_source_and_a_value_is_given(tmp_path):
    """A number further back than a short unit is not the one the comment names; an empty value checks nothing."""
    assert quoted(tmp_path, 'took 590 s in all, two runs at once<!-- = results.json: r["seconds"] -->',
                  {"seconds": 590.3})[1]
    assert "gives no value" in quoted(tmp_path, '3<!-- = results.json: r["x"] -->', {"x": []})[1][0]
    assert quoted(tmp_path, 'p95 2.30 ms<!-- = results.json: r["x"] -->', {"x": 2.3}) == (1, [])
