"""Reports: Markdown tables (the one table writer of every output) and the `Report` of headings,
paragraphs, tables and images rendered to Markdown and standalone HTML."""


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
