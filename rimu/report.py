"""One report layout for every calibration, diagnosis and replay: a self-contained HTML page and a PDF.

A :class:`Report` is a list of blocks (headings, paragraphs, cautions, tables, figures) written twice:
``report.html`` (one file: CSS inline, figures as inline SVG whose text stays text, pictures as data URIs) and
``report.pdf`` (matplotlib's ``PdfPages``: text pages, then each figure on its page, in the order of the blocks).
The cautions the console prints go into the report as they are, in a box above everything else.

Every figure is checked before it is written (:func:`check_figure`): an axes that shows nothing (no artist with
data, or only lines that are identically zero) is removed and named; every remaining axes must label both axes
with a unit in brackets (``[deg/s]``, ``[-]`` for a pure number); titles must lie inside the figure. What
cannot be fixed is listed in ``Report.problems`` (and in the HTML as ``data-problems``), so a test can fail on it.

>>> import matplotlib; matplotlib.use("Agg")
>>> import matplotlib.pyplot as plt
>>> fig, (a, b) = plt.subplots(1, 2)
>>> _ = a.plot([0, 1], [1, 2]); _ = a.set_xlabel("time [s]"); _ = a.set_ylabel("rate [deg/s]")
>>> check_figure(fig)           # the second axes is empty: removed
['removed an empty axes']
>>> len(fig.axes)
1
>>> plt.close(fig)
"""

from __future__ import annotations

import base64
import contextlib
import html
import io
import re
import textwrap
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["Report", "check_figure", "collect_problems", "has_unit"]

_COLLECTORS: list[list[str]] = []


@contextlib.contextmanager
def collect_problems() -> Iterator[list[str]]:
    """Gather what :func:`check_figure` finds wrong in every figure drawn within (for figures saved as PNG by
    their own modules, whose report then states them)."""
    found: list[str] = []
    _COLLECTORS.append(found)
    try:
        yield found
    finally:
        _COLLECTORS.remove(found)

_UNIT = re.compile(r"\[[^\]]+\]")
_CSS = ("body{font-family:sans-serif;max-width:1100px;margin:auto;padding:0 12px;color:#222}"
        "h1{font-size:1.5em}h2{font-size:1.25em;border-bottom:1px solid #ccc}h3{font-size:1.05em}"
        "table{border-collapse:collapse;margin:6px 0;max-width:100%;display:block;overflow-x:auto}"
        "td,th{border:1px solid #ccc;padding:2px 6px;font-size:12px;text-align:right}"
        "th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}"
        ".caution{border-left:4px solid #d98c00;background:#fff6e5;padding:4px 10px;margin:8px 0}"
        ".caution p{margin:3px 0;font-size:13px}figure{margin:10px 0}figure svg,figure img{max-width:100%;"
        "height:auto}figcaption{font-size:12px;color:#555}code{background:#f3f3f3}")


def has_unit(label: str) -> bool:
    """Whether an axis label states its unit in brackets: ``"rate [deg/s]"``, ``"ratio [-]"``."""
    return bool(_UNIT.search(label or ""))


def _empty(ax: Any) -> bool:
    """No artist with data: lines identically zero (reference lines) do not count; bars, images, markers do."""
    import numpy as np

    for ln in ax.get_lines():
        y = np.asarray(ln.get_ydata(), dtype=float)
        y = y[np.isfinite(y)]
        if y.size and (np.max(np.abs(y)) > 0 or ln.get_gid() == "data"):
            return False
    if ax.collections or ax.images:
        return False
    return not any(p.get_height() for p in ax.patches if hasattr(p, "get_height"))


def _numeric(text: str) -> bool:
    try:
        float(text.replace("\u2212", "-").replace("$", "").replace("{", "").replace("}", "").replace("^", "e")
              .replace("\\mathdefault", "").replace("10e", "1e"))
    except ValueError:
        return False
    return True


def check_figure(fig: Any) -> list[str]:
    """Check (and where possible fix) one matplotlib figure for a report; returns what was done or is wrong."""
    notes: list[str] = []
    for ax in list(fig.axes):
        if hasattr(ax, "_colorbar"):
            continue
        if _empty(ax):
            fig.delaxes(ax)
            notes.append("removed an empty axes" + (f" ({ax.get_title()!r})" if ax.get_title() else ""))
    fig.canvas.draw()
    for ax in fig.axes:
        if hasattr(ax, "_colorbar"):
            continue
        for which, lab, shared, ticks in (("x", ax.get_xlabel(), ax.get_shared_x_axes(), ax.get_xticklabels()),
                                          ("y", ax.get_ylabel(), ax.get_shared_y_axes(), ax.get_yticklabels())):
            if has_unit(lab):
                continue
            if any(has_unit(o.get_xlabel() if which == "x" else o.get_ylabel()) for o in shared.get_siblings(ax)):
                continue  # a shared axis labelled once (a column of panels)
            texts = [t.get_text() for t in ticks if t.get_text()]
            if texts and not any(_numeric(t) for t in texts):
                continue  # categories (segment or sensor names): no unit
            notes.append(f"axes {ax.get_title()!r}: {which} label {lab!r} has no unit")
    r = fig.canvas.get_renderer()
    box = fig.bbox
    titles = [ax.title for ax in fig.axes] + ([fig._suptitle] if getattr(fig, "_suptitle", None) else [])
    for t in titles:
        if not t.get_text():
            continue
        e = t.get_window_extent(r)
        if e.x0 < box.x0 - 1 or e.x1 > box.x1 + 1 or e.y1 > box.y1 + 1:
            t.set_text("\n".join(textwrap.wrap(t.get_text(), max(20, int(len(t.get_text()) * box.width / e.width) - 2))))
            fig.canvas.draw()
            e = t.get_window_extent(r)
            if e.x0 < box.x0 - 1 or e.x1 > box.x1 + 1 or e.y1 > box.y1 + 1:
                notes.append(f"title {t.get_text()!r} is clipped")
    for found in _COLLECTORS:
        found.extend(n for n in notes if not n.startswith("removed"))
    return notes


@dataclass
class Report:
    """Blocks of one report (module docstring)."""

    title: str
    blocks: list[tuple[str, Any]] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)

    def heading(self, text: str, level: int = 2) -> None:
        self.blocks.append((f"h{level}", text))

    def text(self, text: str) -> None:
        self.blocks.append(("p", text))

    def cautions(self, lines: list[str]) -> None:
        """The console's cautions and notes, word for word."""
        if lines:
            self.blocks.append(("caution", list(lines)))

    def table(self, header: list[str], rows: list[list[Any]], caption: str = "") -> None:
        self.blocks.append(("table", (list(header), [[str(c) for c in r] for r in rows], caption)))

    def figure(self, fig: Any, caption: str = "") -> None:
        """A matplotlib figure: checked (:func:`check_figure`), embedded as SVG and put on a PDF page."""
        for n in check_figure(fig):
            if not n.startswith("removed"):
                self.problems.append(n)
        self.blocks.append(("figure", (fig, caption)))

    def save_figure(self, index: int, path: str | Path, dpi: int = 100) -> Path | None:
        """Also write the ``index``-th figure as a PNG (whole or not at all); None when there is no such figure."""
        from .atomic import atomic_path

        figs = [v[0] for kind, v in self.blocks if kind == "figure"]
        if index >= len(figs):
            return None
        with atomic_path(Path(path)) as tmp:
            figs[index].savefig(tmp, dpi=dpi, format="png")
        return Path(path)

    def image(self, path: str | Path, caption: str = "") -> None:
        """A picture already drawn (PNG)."""
        self.blocks.append(("image", (Path(path), caption)))

    def markdown(self, md: str, base: str | Path) -> None:
        """Blocks from rimu's report Markdown (headings, tables, images relative to ``base``, paragraphs)."""
        base = Path(base)
        rows: list[list[str]] = []

        def flush() -> None:
            if rows:
                self.table(rows[0], rows[1:])
                rows.clear()

        for line in md.splitlines():
            if line.startswith("|"):
                cells = [c.strip() for c in line.strip().strip("|").split("|")]
                if not set("".join(cells)) <= set("-: "):
                    rows.append(cells)
                continue
            flush()
            if line.startswith("#"):
                n = len(line) - len(line.lstrip("#"))
                self.heading(line[n:].strip(), min(n, 4))
            elif line.startswith("!["):
                alt, src = line[2:].split("](", 1)
                self.image(base / src.rstrip(")"), alt)
            elif line.strip():
                self.text(line.lstrip("-> ").strip())
        flush()

    # ------------------------------------------------------------------ writing
    def html(self) -> str:

        from .atomic import flush_outputs

        flush_outputs()  # the figures its command wrote before (held back by the output group) are read here
        out = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(self.title)}</title>"
               f"<style>{_CSS}</style></head><body data-problems='{html.escape('; '.join(self.problems))}'>",
               f"<h1>{html.escape(self.title)}</h1>"]
        for kind, v in self.blocks:
            if kind.startswith("h"):
                out.append(f"<{kind}>{_inline(v)}</{kind}>")
            elif kind == "p":
                out.append(f"<p>{_inline(v)}</p>")
            elif kind == "caution":
                out.append("<div class='caution'>" + "".join(f"<p>{html.escape(x)}</p>" for x in v) + "</div>")
            elif kind == "table":
                header, rows, caption = v
                out.append("<table>" + (f"<caption>{_inline(caption)}</caption>" if caption else "")
                           + "<tr>" + "".join(f"<th>{_inline(c)}</th>" for c in header) + "</tr>"
                           + "".join("<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in r) + "</tr>" for r in rows)
                           + "</table>")
            elif kind == "figure":
                fig, caption = v
                out.append(f"<figure class='plot'>{_svg(fig)}"
                           + (f"<figcaption>{_inline(caption)}</figcaption>" if caption else "") + "</figure>")
            elif kind == "image":
                path, caption = v
                if path.exists():
                    data = base64.b64encode(path.read_bytes()).decode()
                    out.append(f"<figure class='picture'><img alt='{html.escape(caption)}' "
                               f"src='data:image/png;base64,{data}'>"
                               + (f"<figcaption>{_inline(caption)}</figcaption>" if caption else "") + "</figure>")
        out.append("</body></html>")
        return "\n".join(out)

    def write_pdf(self, target: Any) -> None:
        """All pages into ``target`` (a path or a binary file)."""
        from .atomic import flush_outputs

        flush_outputs()  # the figures its command wrote before (held back by the output group) are read here

        from matplotlib.backends.backend_pdf import PdfPages

        from .plotting import pyplot

        plt = pyplot()
        lines: list[tuple[str, str]] = [("h1", self.title)]
        with PdfPages(target) as pdf:
            def flush() -> None:
                per = 56
                while lines:
                    page, rest = lines[:per], lines[per:]
                    fig = plt.figure(figsize=(8.27, 11.69))
                    y = 0.96
                    for kind, text in page:
                        size = {"h1": 13, "h2": 11, "h3": 10, "h4": 9}.get(kind, 7)
                        fig.text(0.05, y, text, family="monospace", fontsize=size,
                                 color="#a05a00" if kind == "caution" else "black",
                                 weight="bold" if kind.startswith("h") else "normal")
                        y -= 0.0165 * (1.4 if kind.startswith("h") else 1.0)
                    pdf.savefig(fig)
                    plt.close(fig)
                    lines[:] = rest

            for kind, v in self.blocks:
                if kind.startswith("h"):
                    lines.append((kind, str(v)))
                elif kind in ("p", "caution"):
                    for x in ([v] if kind == "p" else v):
                        for w in textwrap.wrap(str(x).replace("**", "").replace("`", ""), 118) or [""]:
                            lines.append((kind, w))
                elif kind == "table":
                    header, rows, _ = v
                    width = [max(len(str(c)) for c in col) for col in zip(header, *rows)]
                    for r in [header] + rows:
                        lines.append(("t", "  ".join(str(c).replace("**", "").ljust(w) for c, w in zip(r, width))[:130]))
                elif kind == "figure":
                    flush()
                    pdf.savefig(v[0])
                elif kind == "image" and v[0].exists():
                    flush()
                    img = plt.imread(str(v[0]))
                    fig = plt.figure(figsize=(8.27, 8.27 * img.shape[0] / img.shape[1] + 0.3))
                    ax = fig.add_axes((0, 0, 1, 1))
                    ax.imshow(img)
                    ax.set_axis_off()
                    pdf.savefig(fig)
                    plt.close(fig)
            flush()

    def write(self, directory: str | Path, stem: str = "report", pdf: bool = True) -> tuple[Path, Path | None]:
        """Write ``stem.html`` and ``stem.pdf`` into ``directory`` (created), whole or not at all; close the
        figures. Returns the two paths (PDF None when ``pdf`` is False)."""
        from .atomic import atomic_files, flush_outputs

        flush_outputs()  # the figures this command wrote before (held back by its output group) are read here
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        h, p = directory / f"{stem}.html", directory / f"{stem}.pdf"
        try:
            with atomic_files() as tx:
                tx.path(h).write_text(self.html())
                if pdf:
                    self.write_pdf(tx.path(p))
        finally:
            from .plotting import pyplot

            plt = pyplot()
            for kind, v in self.blocks:
                if kind == "figure":
                    plt.close(v[0])
        return h, (p if pdf else None)


def _svg(fig: Any) -> str:
    import matplotlib

    for i, ax in enumerate(fig.axes):  # named, so that a browser can find the labels and titles
        if not hasattr(ax, "_colorbar"):
            for name, t in (("xlabel", ax.xaxis.label), ("ylabel", ax.yaxis.label), ("title", ax.title)):
                if t.get_text():
                    t.set_gid(f"{name}-{i}")
    if getattr(fig, "_suptitle", None) is not None:
        fig._suptitle.set_gid("suptitle")
    buf = io.StringIO()
    with matplotlib.rc_context({"svg.fonttype": "none"}):  # text stays text: searchable, measurable
        fig.savefig(buf, format="svg")
    s = buf.getvalue()
    return s[s.index("<svg"):]


def _inline(s: str) -> str:
    s = html.escape(str(s))
    parts = s.split("**")
    s = "".join(f"<b>{p}</b>" if k % 2 else p for k, p in enumerate(parts))
    parts = s.split("`")
    return "".join(f"<code>{p}</code>" if k % 2 else p for k, p in enumerate(parts))
