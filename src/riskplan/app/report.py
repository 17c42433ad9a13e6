"""A small self-contained HTML report: sections of text, tables, PNG figures and
interactive plotly pages, written atomically to ``OUT/report.html``."""

from __future__ import annotations

import datetime as _dt
import html
from dataclasses import dataclass, field
from pathlib import Path

from riskplan.io import write_text_atomic


@dataclass
class Section:
    title: str
    blocks: list[str] = field(default_factory=list)


class Report:
    """Collects sections; figures are files in ``out`` referenced by relative path."""

    def __init__(self, out, title: str = "riskplan report"):
        self.out = Path(out)
        self.out.mkdir(parents=True, exist_ok=True)
        self.title = title
        self.sections: list[Section] = []

    def section(self, title: str) -> Section:
        s = Section(title)
        self.sections.append(s)
        return s

    @staticmethod
    def text(section: Section, text: str) -> None:
        section.blocks.append(f"<p>{html.escape(text)}</p>")

    @staticmethod
    def pre(section: Section, text: str) -> None:
        section.blocks.append(f"<pre>{html.escape(text)}</pre>")

    @staticmethod
    def table(
        section: Section, header: list[str], rows: list[list], caption: str | None = None
    ) -> None:
        def cell(v):
            return f"{v:.4g}" if isinstance(v, float) else html.escape(str(v))

        head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
        body = "".join("<tr>" + "".join(f"<td>{cell(v)}</td>" for v in r) + "</tr>" for r in rows)
        cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
        section.blocks.append(
            f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"
        )

    def figure(self, section: Section, fig, name: str, caption: str = "", dpi: int = 110) -> Path:
        """Save a matplotlib figure as ``OUT/name.png``, close it, and show it in the section."""
        import matplotlib.pyplot as plt

        path = self.out / f"{name}.png"
        fig.savefig(path, dpi=dpi, bbox_inches="tight")
        plt.close(fig)
        self.image(section, path, caption)
        return path

    def image(self, section: Section, path, caption: str = "") -> None:
        rel = Path(path).relative_to(self.out).as_posix()
        section.blocks.append(
            f'<figure><img src="{html.escape(rel)}" alt="{html.escape(caption or rel)}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>"
        )

    def plotly(self, section: Section, fig, name: str, caption: str = "") -> Path:
        """Write an interactive plotly page ``OUT/name.html`` (plotly.js once, beside it) and link it."""
        path = self.out / f"{name}.html"
        fig.write_html(path, include_plotlyjs="directory", full_html=True)
        section.blocks.append(
            f'<p><a href="{html.escape(path.name)}">{html.escape(caption or name)} (interactive 3-D view)</a></p>'
        )
        return path

    def write(self) -> Path:
        parts = [
            "<!doctype html><html><head><meta charset='utf-8'>",
            f"<title>{html.escape(self.title)}</title>",
            "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;line-height:1.4}"
            "img{max-width:100%}table{border-collapse:collapse;margin:1em 0}"
            "td,th{border:1px solid #bbb;padding:3px 8px;text-align:right}"
            "figure{margin:1em 0}figcaption{color:#555;font-size:90%}pre{background:#f4f4f4;padding:8px}</style>",
            "</head><body>",
            f"<h1>{html.escape(self.title)}</h1>",
            f"<p>Generated {_dt.datetime.now().isoformat(timespec='seconds')}.</p>",
            "<ul>"
            + "".join(
                f"<li><a href='#s{i}'>{html.escape(s.title)}</a></li>"
                for i, s in enumerate(self.sections)
            )
            + "</ul>",
        ]
        for i, s in enumerate(self.sections):
            parts.append(f"<h2 id='s{i}'>{html.escape(s.title)}</h2>")
            parts.extend(s.blocks)
        parts.append("</body></html>")
        path = self.out / "report.html"
        write_text_atomic(path, "\n".join(parts))
        return path
