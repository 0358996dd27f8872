"""MISRA C:2012 over the generated flight code (``rimu_unit.c`` / ``rimu_unit.h``) with cppcheck's MISRA addon,
and the project's deviations from it.

The rule texts are licensed by MISRA and are not shipped: :data:`DEVIATIONS` names each rule the generated code
departs from by number, with its category and the reason (the same list is in docs/flight-target.md).
:func:`misra_check` runs ``cppcheck --addon=misra`` and returns the findings per rule; anything whose rule is not
in :data:`DEVIATIONS`, and any other cppcheck finding, is a defect of the exporter.

>>> sorted(DEVIATIONS)[:3], {category for category, _ in DEVIATIONS.values()}
(['12.1', '12.3', '13.4'], {'advisory'})
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
    "8.7": ("advisory", "the per-instrument steps are the public interface, called from the flight software's own "
                        "translation units"),
    "8.9": ("advisory", "the calibration tables stay at file scope beside the constants they are generated with"),
    "12.1": ("advisory", "operator precedence of arithmetic and comparison is left to C's rules, as in the papers' "
                         "formulas"),
    "12.3": ("advisory", "several variables are declared in one declaration"),
    "13.4": ("advisory", "chained assignments zero several accumulators (a = b = 0)"),
    "15.5": ("advisory", "early returns where a test decides (unobservable set, nothing to decide)"),
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
