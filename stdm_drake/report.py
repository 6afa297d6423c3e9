"""Reports: Markdown tables (the one table writer of every output), the `Report` of headings, paragraphs, tables
and images rendered to Markdown and standalone HTML, and the open-loop error line beside the physics-free
rollouts (`open_loop_error_line`, what `view` prints per trajectory)."""
import numpy as np


def markdown_table(header, rows) -> str:
    """A Markdown table: `header` (n cells) and `rows` (each n cells, any values, shown with str())."""
    lines = ["| " + " | ".join(str(cell) for cell in header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(cell) for cell in row) + " |" for row in rows]
    return "\n".join(lines)


class Report:
    """A report of headings, paragraphs, tables and images, rendered to Markdown and to a standalone
    HTML page."""

    def __init__(self, title):
        self.title = title
        self.blocks = []

    def heading(self, text):
        self.blocks.append(("h2", text))

    def text(self, text):
        self.blocks.append(("p", text))

    def table(self, header, rows):
        self.blocks.append(("table", header, rows))

    def image(self, path, caption):
        self.blocks.append(("img", path, caption))

    def markdown(self):
        out = [f"# {self.title}", ""]
        for block in self.blocks:
            if block[0] == "h2":
                out += [f"## {block[1]}", ""]
            elif block[0] == "p":
                out += [block[1], ""]
            elif block[0] == "table":
                out += [markdown_table(block[1], block[2]), ""]
            else:
                out += [f"![{block[2]}]({block[1]})", "", f"*{block[2]}*", ""]
        return "\n".join(out)

    def html(self):
        import html
        out = ["<!DOCTYPE html><html><head><meta charset='utf-8'>", f"<title>{html.escape(self.title)}</title>",
               "<style>body{font-family:sans-serif;max-width:1100px;margin:auto}table{border-collapse:collapse}"
               "td,th{border:1px solid #bbb;padding:3px 8px;text-align:right}img{max-width:100%}</style></head><body>",
               f"<h1>{html.escape(self.title)}</h1>"]
        for block in self.blocks:
            if block[0] == "h2":
                out.append(f"<h2>{html.escape(block[1])}</h2>")
            elif block[0] == "p":
                out.append(f"<p>{html.escape(block[1])}</p>")
            elif block[0] == "table":
                out.append("<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in block[1]) + "</tr>")
                out += ["<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>" for row in block[2]]
                out.append("</table>")
            else:
                out.append(f"<figure><img src='{html.escape(block[1])}'><figcaption>{html.escape(block[2])}"
                           "</figcaption></figure>")
        return "\n".join(out + ["</body></html>"])


def open_loop_error_line(name: str, q: np.ndarray, v0: np.ndarray, predicted: np.ndarray, sample_period: float,
                         steps=(1, 10, 50)) -> str:
    """One line of open-loop joint-angle errors: the RMS over joints of predicted - q at a few steps
    (those of `steps` within the trajectory, and its last), beside the physics-free rollouts from the
    same start, "stays put" (q_0 held) and "v unchanged" (q_0 + k h v_0), and the step from which on the model
    is further off than staying put, or the first such step and how many there are where it is closer again (a
    rollout's error grows with the horizon, so a long trajectory's whole-length figure alone says little).

    q, predicted: (T + 1, n) rad, both starting at q_0; v0: (n,) rad/s; sample_period h: s."""
    last = len(q) - 1
    shown = [k for k in steps if k < last] + [last]
    k = np.arange(len(q))[:, None]
    rollouts = {name: predicted, "stays put": np.broadcast_to(q[0], q.shape),
                "v unchanged": q[0] + k * sample_period * v0}
    errors = {label: np.sqrt(np.mean((rollout - q) ** 2, axis=1)) for label, rollout in rollouts.items()}
    table = "; ".join(f"{label} " + " / ".join(f"{error[step]:.3g}" for step in shown)
                      for label, error in errors.items())
    worse = np.flatnonzero(errors[name][1:] > errors["stays put"][1:])
    if not len(worse):
        verdict = "closer than staying put throughout"
    elif len(worse) == last - worse[0]:   # (every step from the first worse one to the end)
        verdict = f"further off than staying put from step {worse[0] + 1} on"
    else:
        verdict = f"further off than staying put first at step {worse[0] + 1} (on {len(worse)} of {last} steps)"
    return (f"open-loop RMS joint-angle error (rad) at steps {' / '.join(map(str, shown))}: {table}; "
            f"{name} {verdict}")
