"""The budgets of the Cortex-M4 build (:mod:`rimu.export.target`): flash and RAM from the flight image's link map,
the worst-case stack of ``rimu_fdi_step`` over its whole call graph, and the checks that the graph has no recursion
and no dynamic memory.

Stack: each function's frame is its ``-fstack-usage`` figure for the generated code (``rimu_unit.su``; a frame
GCC reports as ``dynamic`` is refused) and, for the C library and libgcc functions the flight image links, the
sum of its prologue's ``push``/``vpush``/``sub sp`` in the
disassembly. The call graph is every ``bl``/``b`` to a function symbol in ``arm-none-eabi-objdump -d`` of the
flight image; the worst case is the deepest path from ``rimu_fdi_step`` (a tail call counted as a call, so the
bound is safe). An indirect call (``blx rN``) reachable from ``rimu_fdi_step`` makes the bound unknown, and is
reported as such.
"""

from __future__ import annotations

import re
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import ExportError

__all__ = ["ALLOC", "Budget", "link_sizes", "measure", "stack_graph"]

#: dynamic memory: none of these may be reachable from the flight code
ALLOC = ("malloc", "calloc", "realloc", "free", "_malloc_r", "_calloc_r", "_realloc_r", "_free_r", "_sbrk", "sbrk")

_FUNC = re.compile(r"^([0-9a-f]+) <([^>]+)>:$")
_CALL = re.compile(r"\t(bl|b|b\.w|b\.n)\s+[0-9a-f]+ <([^>+]+)>")
_PUSH = re.compile(r"\t(push|stmdb\s+sp!,|stmfd\s+sp!,)\s*\{([^}]*)\}")
_VPUSH = re.compile(r"\tvpush\s*\{([^}]*)\}")
_PRE = re.compile(r"\tstr[a-z.]*\s+[^\[]*\[sp, #-(\d+)\]!")   # str.w lr, [sp, #-8]! (a push with padding)
_SUB = re.compile(r"\tsub(?:w|\.w)?\s+sp,\s*(?:sp,\s*)?#(\d+)")


def _regs(text: str) -> list[str]:
    """The registers of a ``push``/``vpush`` list.

    >>> _regs("r4, r5, lr"), _regs("d8-d10")
    (['r4', 'r5', 'lr'], ['d8', 'd9', 'd10'])
    """
    out = []
    for part in (p.strip() for p in text.split(",")):
        if "-" in part:
            a, b = part.split("-")
            out += [f"{a[0]}{i}" for i in range(int(a[1:]), int(b[1:]) + 1)]
        elif part:
            out.append(part)
    return out


def _frames_from_su(su: Path) -> tuple[dict[str, int], list[str]]:
    """Frames per function from GCC's stack usage: the ``.ci`` call-graph file of ``-fcallgraph-info=su`` beside
    ``su`` when there is one (it names each clone, ``rimu_fit_set.constprop.0``), else the ``.su`` file (clones
    share a name there: the largest frame is taken)."""
    frames: dict[str, int] = {}
    dynamic = []
    ci = su.with_suffix(".ci")
    if ci.exists():
        for m in re.finditer(r'node: \{ title: "(?:[^"]*:)?([^":]+)" label: "[^"]*\\n(\d+) bytes \(([^)]*)\)"',
                             ci.read_text()):
            frames[m.group(1)] = int(m.group(2))
            if m.group(3) != "static":
                dynamic.append(m.group(1))
        return frames, dynamic
    for line in su.read_text().splitlines():
        loc, size, kind = line.rsplit("\t", 2)
        name = loc.rsplit(":", 1)[-1]
        frames[name] = max(frames.get(name, 0), int(size))
        if kind != "static":
            dynamic.append(name)
    return frames, dynamic


@dataclass
class StackGraph:
    """The call graph of the flight image: each function's frame (bytes), where it came from, and its callees."""

    frames: dict[str, int] = field(default_factory=dict)
    source: dict[str, str] = field(default_factory=dict)
    calls: dict[str, set[str]] = field(default_factory=dict)
    indirect: set[str] = field(default_factory=set)
    dynamic: list[str] = field(default_factory=list)

    def reachable(self, root: str) -> set[str]:
        seen, todo = set(), [root]
        while todo:
            f = todo.pop()
            if f in seen:
                continue
            seen.add(f)
            todo += [c for c in self.calls.get(f, ()) if c in self.frames]
        return seen

    def cycle(self, root: str) -> list[str] | None:
        """A call cycle (recursion) reachable from ``root``, or None."""
        colour: dict[str, int] = {}
        path: list[str] = []

        def visit(f: str) -> list[str] | None:
            colour[f] = 1
            path.append(f)
            for c in sorted(self.calls.get(f, ())):
                if c == f or colour.get(c) == 1:
                    return path[path.index(c):] + [c] if c in path else [f, c]
                if colour.get(c, 0) == 0 and c in self.frames:
                    found = visit(c)
                    if found:
                        return found
            path.pop()
            colour[f] = 2
            return None

        return visit(root)

    def worst(self, root: str) -> tuple[int, list[str]]:
        """The deepest stack from ``root`` (bytes) and its path (the graph must be acyclic)."""
        memo: dict[str, tuple[int, list[str]]] = {}

        def depth(f: str) -> tuple[int, list[str]]:
            if f not in memo:
                best: tuple[int, list[str]] = (0, [])
                for c in self.calls.get(f, ()):
                    if c in self.frames and c != f:
                        best = max(best, depth(c))
                memo[f] = (self.frames[f] + best[0], [f] + best[1])
            return memo[f]

        return depth(root)


def stack_graph(elf: str | Path, su: str | Path | None = None, objdump: str = "arm-none-eabi-objdump") -> StackGraph:
    """The call graph and frames of ``elf`` (frames of the generated code from ``su``, the others from their
    prologues)."""
    text = subprocess.run([objdump, "-d", "--no-show-raw-insn", str(elf)], capture_output=True, text=True,
                          check=True).stdout
    g = StackGraph()
    su_frames, g.dynamic = _frames_from_su(Path(su)) if su else ({}, [])
    fn = None
    for line in text.splitlines():
        m = _FUNC.match(line)
        if m:
            fn = m.group(2)
            g.frames[fn] = 0
            g.calls[fn] = set()
            g.source[fn] = "prologue"
            continue
        if fn is None:
            continue
        m = _CALL.search(line)
        if m:  # a call of itself included: recursion
            g.calls[fn].add(m.group(2))
        if re.search(r"\tblx\s+r\d+", line):
            g.indirect.add(fn)
        m = _PUSH.search(line)
        if m:
            g.frames[fn] += 4 * len(_regs(m.group(2)))
        m = _VPUSH.search(line)
        if m:
            g.frames[fn] += sum(8 if r.startswith("d") else 4 for r in _regs(m.group(1)))
        for rx in (_SUB, _PRE):
            m = rx.search(line)
            if m:
                g.frames[fn] += int(m.group(1))
        if re.search(r"\t(sub|add)[a-z.]*\s+sp, (sp, )?r\d+|\tmov[a-z.]*\s+sp, r\d+", line):
            g.dynamic.append(fn)   # the stack pointer moved by a register: no static frame
    for fn in g.frames:
        key = fn if fn in su_frames else fn.rsplit(".", 1)[0] if fn.rsplit(".", 1)[0] in su_frames else None
        if key is not None:
            g.frames[fn] = su_frames[key]
            g.source[fn] = "-fstack-usage"
    return g


_MAPLINE = re.compile(r"^ (\.[\w.$]+)?\s+0x([0-9a-f]+)\s+0x([0-9a-f]+)\s+(\S+)$")


def link_sizes(mapfile: str | Path) -> dict[str, dict[str, int]]:
    """Bytes per object file of the image in a GNU ld map: ``{file: {"flash": ..., "ram": ...}}`` (flash: code,
    constants and initial data; RAM: data and zero-initialised data). Library members are grouped by archive."""
    out: dict[str, dict[str, int]] = {}
    lines = Path(mapfile).read_text().splitlines()
    start = next((i for i, ln in enumerate(lines) if ln.startswith("Linker script and memory map")), 0)
    pending = None
    for ln in lines[start:]:
        if ln.startswith(" .") and len(ln.split()) == 1:
            pending = ln.split()[0]
            continue
        m = _MAPLINE.match(ln)
        if not m:
            pending = None
            continue
        sec = m.group(1) or pending or ""
        pending = None
        size, origin = int(m.group(3), 16), m.group(4)
        if size == 0 or (int(m.group(2), 16) == 0 and not sec.startswith(".vectors")):
            continue   # discarded or not placed
        key = Path(origin.split("(")[0]).name
        rec = out.setdefault(key, {"flash": 0, "ram": 0})
        if sec.startswith((".text", ".rodata", ".ARM", ".vectors", ".init", ".fini", ".glue", ".vfp11")):
            rec["flash"] += size
        elif sec.startswith(".data"):
            rec["flash"] += size
            rec["ram"] += size
        elif sec.startswith((".bss", "COMMON")):
            rec["ram"] += size
    return out


@dataclass
class Budget:
    """The flight image's budgets (bytes): flash and RAM of the generated code, of the state and buffers of the
    flight loop and of the library code it links; the worst-case stack of ``rimu_fdi_step`` and its path."""

    flash_code: int
    ram_code: int
    flash_library: int
    ram_library: int
    ram_state: int
    stack: int
    stack_path: list[str]
    library_functions: list[str]

    @property
    def flash(self) -> int:
        return self.flash_code + self.flash_library

    @property
    def ram(self) -> int:
        """Static RAM of the flight code: its data, the state and buffers, the library's data (no stack)."""
        return self.ram_code + self.ram_state + self.ram_library


def measure(directory: str | Path, root: str = "rimu_fdi_step") -> Budget:
    """Budgets of a built target (:func:`rimu.export.target.build_target`) from ``rimu_flight.map``,
    ``rimu_flight.elf`` and ``rimu_unit.su``. Raises :class:`ExportError` on recursion, dynamic memory, a
    dynamic stack frame or an indirect call reachable from ``root``."""
    d = Path(directory)
    g = stack_graph(d / "rimu_flight.elf", d / "rimu_unit.su")
    if root not in g.frames:
        raise ExportError(f"{root} is not in the flight image")
    reach = g.reachable(root)
    cyc = g.cycle(root)
    if cyc:
        raise ExportError(f"recursion in the flight code: {' -> '.join(cyc)}")
    alloc = sorted(reach & set(ALLOC))
    if alloc:
        raise ExportError(f"the flight code reaches dynamic memory: {', '.join(alloc)}")
    if g.dynamic:
        raise ExportError(f"dynamic stack frames: {', '.join(g.dynamic)}")
    ind = sorted(reach & g.indirect)
    if ind:
        raise ExportError(f"indirect calls in the flight code (the stack bound is unknown): {', '.join(ind)}")
    stack, path = g.worst(root)
    sizes = link_sizes(d / "rimu_flight.map")
    code = sizes.get("rimu_unit.o", {"flash": 0, "ram": 0})
    state = sizes.get("rimu_flight.o", {"flash": 0, "ram": 0})
    lib = {"flash": 0, "ram": 0}
    for k, v in sizes.items():
        if k.endswith(".a"):
            lib["flash"] += v["flash"]
            lib["ram"] += v["ram"]
    libfn = sorted(f for f in reach if g.source.get(f) == "prologue")
    return Budget(code["flash"], code["ram"], lib["flash"], lib["ram"], state["ram"], stack, path, libfn)
