"""MISRA C:2012 over the generated flight code (``rimu_unit.c`` / ``rimu_unit.h``) with cppcheck's MISRA addon,
and the project's deviations from it.

The rule texts are licensed by MISRA and are not shipped: :data:`DEVIATIONS` names each rule the generated code
departs from by number, with its category and the reason (the same list is in docs/flight-target.md).
:func:`misra_check` runs ``cppcheck --addon=misra`` and returns the findings per rule; anything whose rule is not
in :data:`DEVIATIONS`, and any other cppcheck finding, is a defect of the exporter.

>>> sorted(DEVIATIONS)[:3]
['10.3', '10.4', '10.5']
"""

from __future__ import annotations

import re
import shutil
import subprocess
from collections import Counter
from pathlib import Path

from ..errors import ExportError

__all__ = ["DEVIATIONS", "misra_check"]

#: rule -> (category, reason for the deviation). Categories as MISRA classifies the rules.
DEVIATIONS: dict[str, tuple[str, str]] = {
    "2.4": ("advisory", "the decision codes of the isolation test are an unnamed enum used as constants"),
    "2.5": ("advisory", "the header defines macros for the caller (sensor counts, codes, what rimu_step reads) that "
                        "the unit itself does not use"),
    "8.7": ("advisory", "the per-instrument steps and rimu_chi2_isf are the public interface, called from the "
                        "flight software's own translation units"),
    "8.9": ("advisory", "the calibration tables stay at file scope beside the constants they are generated with"),
    "10.3": ("required", "integer results of comparisons are stored in int flags (C99's boolean idiom), and "
                         "integer constants 0 and 1 initialise floating variables; each conversion is exact"),
    "10.4": ("required", "integer constants (0, 1, 2) appear in floating expressions; each is exactly "
                         "representable and converted at compile time"),
    "10.5": ("advisory", "flags (int, from comparisons) are cast to unsigned char to store sensor masks in a byte"),
    "10.6": ("required", "a conditional expression of enumeration-like int constants is assigned to an int "
                         "(same width on every target)"),
    "10.7": ("required", "a count of sensor pairs is computed in long from int operands bounded by RIMU_NMAX"),
    "12.1": ("advisory", "operator precedence of arithmetic and comparison is left to C's rules, as in the papers' "
                         "formulas"),
    "12.3": ("advisory", "several variables are declared in one declaration"),
    "13.3": ("advisory", "a candidate list is appended to with cand[mm++] = i"),
    "13.4": ("advisory", "chained assignments zero several accumulators (a = b = 0)"),
    "14.4": ("required", "int flags and pointers are tested directly (if (alarm), if (z)); every one holds 0 or 1, "
                         "or is a pointer tested against NULL"),
    "15.5": ("advisory", "early returns where a test decides (unobservable set, nothing to decide)"),
    "15.6": ("required", "one-statement loop and if bodies are written without braces"),
}

_LINE = re.compile(r"^(?P<file>[^:]+):(?P<line>\d+):(?P<id>\S+)$")


def misra_check(directory: str | Path, files: tuple[str, ...] = ("rimu_unit.c", "rimu_unit.h"),
                timeout: float = 300.0) -> dict[str, Counter]:
    """Run cppcheck's MISRA C:2012 addon over the generated flight code in ``directory``.

    Returns ``{"misra": Counter(rule -> findings), "other": Counter(cppcheck id -> findings)}``. Raises
    :class:`ExportError` when cppcheck is not installed."""
    from ..atomic import flush_outputs

    flush_outputs()  # a command's held-back outputs are what this reads: in place

    exe = shutil.which("cppcheck")
    if exe is None:
        raise ExportError("cppcheck is not installed (Debian: apt-get install cppcheck)")
    res = subprocess.run([exe, "--addon=misra", "--std=c99", "--quiet", "--template={file}:{line}:{id}",
                          *files], cwd=Path(directory), capture_output=True, text=True, timeout=timeout)
    misra: Counter = Counter()
    other: Counter = Counter()
    for ln in (res.stderr + res.stdout).splitlines():
        m = _LINE.match(ln.strip())
        if not m:
            continue
        ident = m.group("id")
        if ident.startswith("misra-c2012-"):
            misra[ident.removeprefix("misra-c2012-")] += 1
        else:
            other[ident] += 1
    return {"misra": misra, "other": other}
