"""The exported filter and fault management on a flight computer's processor: a Cortex-M4F in single precision,
run under QEMU's ``mps2-an386`` board (a Cortex-M4 with FPU).

:func:`write_target` exports a calibration in ``float`` (:func:`rimu.export.export_c`) and adds, beside the
desktop sources,

* ``rimu_target.c``: a harness that streams a recorded raw input (``rimu_input.bin``, written by
  :func:`write_input`) through ``rimu_fdi_step`` and writes the estimates file (:mod:`rimu.export.estimates`) and
  the detail of every decision (``rimu_detail.csv``: the columns of ``rimu_filter --detail``), reading and writing
  through semihosting on the target, through the C library on a desktop; on the target it also counts each
  epoch's instructions (SysTick under ``-icount``) and the stack each epoch used (a painted stack);
* ``rimu_flight.c``: the smallest program that flies the unit (state, one ``rimu_fdi_step`` per epoch, no I/O),
  whose link map gives the flash and RAM of the flight code (:mod:`rimu.export.target_budget`);
* ``rimu_m4_startup.c`` and ``rimu_m4.ld``: the vector table, reset handler (FPU on, ``.data`` copied,
  ``.bss`` zeroed) and memory map of the board;
* ``Makefile.cortex-m4``: ``make -f Makefile.cortex-m4`` builds ``rimu_target.elf``, ``rimu_target_stats.elf``
  (the harness running ``rimu_step``, without fault management, for its instruction count) and ``rimu_flight.elf``
  with ``arm-none-eabi-gcc -mcpu=cortex-m4 -mfpu=fpv4-sp-d16 -mfloat-abi=hard``, and ``rimu_target_host``, the
  same harness and unit built for the desktop with the same floating-point settings (``-ffp-contract=off`` on
  both, so no multiply-add is fused on one side only and the two outputs can be compared bit for bit).

:func:`build_target` runs that Makefile, :func:`run_target` streams an input through the harness under
``qemu-system-arm -M mps2-an386 -icount shift=0 -semihosting-config enable=on,target=native`` (or through the
desktop build), :func:`toolchain` says which of the tools are installed.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..calibration.result import Calibration
from ..errors import ExportError
from .c99 import export_c
from .c_fdi import FdiSettings

__all__ = ["CPU_FLAGS", "FP_FLAGS", "QEMU_BOARD", "TOOLS", "TargetRun", "build_target", "input_dtype", "missing_tools",
           "run_target", "synthetic_unit", "write_input", "write_target"]

#: the processor: a Cortex-M4 with its single-precision FPU, hard-float calling convention
CPU_FLAGS = ("-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard")
#: floating point pinned on the target and the desktop alike: no fused multiply-add, math functions without errno
FP_FLAGS = ("-ffp-contract=off", "-fno-math-errno")
QEMU_BOARD = "mps2-an386"
#: executables the target build and run need (Debian: gcc-arm-none-eabi, libnewlib-arm-none-eabi, qemu-system-arm)
TOOLS = ("arm-none-eabi-gcc", "arm-none-eabi-objdump", "qemu-system-arm", "make")
#: the board's SysTick runs on the 25 MHz system clock; under ``-icount shift=0`` one instruction is 1 ns
SYSTICK_HZ = 25e6


def missing_tools() -> list[str]:
    """The tools of :data:`TOOLS` (and a host C compiler) that are not installed."""
    miss = [t for t in TOOLS if shutil.which(t) is None]
    if "arm-none-eabi-gcc" not in miss:  # the C library of the Cortex-M4F (newlib)
        lib = subprocess.run(["arm-none-eabi-gcc", *CPU_FLAGS, "-print-file-name=libc.a"], capture_output=True,
                             text=True).stdout.strip()
        if not Path(lib).is_absolute():
            miss.append("libnewlib-arm-none-eabi")
    if not any(shutil.which(c) for c in ("cc", "gcc", "clang")):
        miss.append("cc")
    return miss


def synthetic_unit(geometry: Any, instruments: tuple[str, ...] = ("gyro", "accel"), seed: int = 0) -> Calibration:
    """A calibrated unit of ``geometry`` for the target's tests and benchmark (one definition for both): nominal
    axes, scale factors of 0.01 SI per raw unit with a 1 % spread, biases of 0.3 SI, noise of 0.002 rad/s (gyros)
    and 0.02 m/s^2 (accelerometers) per sample with a 20 % spread, drawn from ``seed``.

    >>> from rimu.geometry import cone6
    >>> cal = synthetic_unit(cone6(), ("gyro",))
    >>> list(cal.instruments), cal["gyro"].geometry.n, bool(0.0099 < cal["gyro"].scale.mean() < 0.0101)
    (['gyro'], 6, True)
    """
    from ..calibration.result import InstrumentCalibration

    cals = {}
    for k in instruments:
        rng = np.random.default_rng([seed, geometry.n, ("gyro", "accel").index(k)])
        c = InstrumentCalibration.nominal(k, geometry, scale=1.0, noise_sigma=(0.002 if k == "gyro" else 0.02)
                                          * (1 + 0.2 * rng.random(geometry.n)))
        c.scale = 0.01 * (1 + 0.01 * rng.standard_normal(geometry.n))
        c.bias = 0.3 * rng.standard_normal(geometry.n)
        cals[k] = c
    return Calibration(cals)


def _prefix(k: str) -> str:
    return {"gyro": "RIMU_GYRO", "accel": "RIMU_ACCEL"}[k]


def input_dtype(cal: Calibration) -> np.dtype:
    """One epoch of ``rimu_input.bin``: ``t`` (s, double), ``temperature`` (degC, double), then per instrument the
    raw values (float, the target's ``rimu_real``) and their validity flags (one byte each), packed.

    >>> from rimu.calibration.result import Calibration, InstrumentCalibration
    >>> from rimu.geometry import cone6
    >>> cal = Calibration({"gyro": InstrumentCalibration.nominal("gyro", cone6(), noise_sigma=0.01)})
    >>> input_dtype(cal).itemsize   # t and temperature (8 + 8), 6 floats (24), 6 flags (6)
    46
    """
    fields: list[tuple[str, Any, Any]] = [("t", "<f8", ()), ("temperature", "<f8", ())]
    for k in cal.instruments:
        n = cal[k].geometry.n
        fields += [(f"{k}_y", "<f4", (n,)), (f"{k}_valid", "u1", (n,))]
    return np.dtype([(name, typ, shape) for name, typ, shape in fields])


def write_input(path: str | os.PathLike[str], cal: Calibration, t: np.ndarray, raw: dict[str, np.ndarray],
                valid: dict[str, np.ndarray] | None = None, temperature: np.ndarray | None = None) -> int:
    """Write a raw stream as ``rimu_input.bin`` (:func:`input_dtype`); the raw values are rounded to float as the
    desktop filter rounds what it reads (``(rimu_real)strtod``). Returns the number of epochs."""
    t = np.asarray(t, dtype=float)
    rec = np.zeros(len(t), dtype=input_dtype(cal))
    rec["t"] = t
    rec["temperature"] = 0.0 if temperature is None else np.asarray(temperature, dtype=float)
    for k in cal.instruments:
        y = np.asarray(raw[k], dtype=float)
        ok = np.isfinite(y) if valid is None else (np.asarray(valid[k], bool) & np.isfinite(y))
        rec[f"{k}_y"] = np.where(ok, y, 0.0).astype(np.float32)
        rec[f"{k}_valid"] = ok
    Path(path).write_bytes(rec.tobytes())
    return len(t)


_SYSTICK = r"""
#ifdef RIMU_CORTEX_M
/* SysTick on the processor clock: under QEMU's -icount it counts executed instructions (one per 40 at 25 MHz) */
#define SYST_CSR (*(volatile unsigned long *)0xE000E010u)
#define SYST_RVR (*(volatile unsigned long *)0xE000E014u)
#define SYST_CVR (*(volatile unsigned long *)0xE000E018u)
#define PAINT_WORDS 4096u
#define PAINT 0xA5A5A5A5u
static void tick_start(void) { SYST_RVR = 0x00FFFFFFu; SYST_CVR = 0u; SYST_CSR = 5u; }
static unsigned long tick_now(void) { return SYST_CVR; }
static unsigned long ticks(unsigned long a, unsigned long b) { return (a - b) & 0x00FFFFFFu; }  /* counts down */
static unsigned long sp_now(void) { unsigned long sp; __asm volatile ("mov %0, sp" : "=r" (sp)); return sp; }
/* a loop of 2 instructions (subs, bne) n times: the instructions per SysTick tick, measured */
static unsigned long known_loop(unsigned long n)
{
    unsigned long a = tick_now(), b;
    __asm volatile ("1: subs %0, %0, #1\n bne 1b" : "+r" (n) : : "cc");
    b = tick_now();
    return ticks(a, b);
}
#else
static void tick_start(void) { }
static unsigned long tick_now(void) { return 0u; }
static unsigned long ticks(unsigned long a, unsigned long b) { return a - b; }
static unsigned long known_loop(unsigned long n) { return n - n; }
#endif
"""


def _harness(cal: Calibration) -> str:
    insts = list(cal.instruments)
    decl = "\n".join(f"static rimu_real y_{k}[{_prefix(k)}_N];\nstatic unsigned char v_{k}[{_prefix(k)}_N];\n"
                     f"static rimu_fdi m_{k};\nstatic rimu_fdi_output f_{k};" for k in insts)
    reads = "\n".join(f"        ok = ok && fread(y_{k}, sizeof y_{k}, 1, in) == 1 && fread(v_{k}, sizeof v_{k}, 1, in) "
                      "== 1;" for k in insts)
    call = "RIMU_HARNESS_STEP;"
    fdi_call = "rimu_fdi_step((rimu_real)(t - t0), (rimu_real)temp, " + \
        ", ".join(f"&m_{k}, y_{k}, v_{k}, &f_{k}" for k in insts) + ")"
    stats_decl = "\n".join(f"static rimu_state s_{k};\nstatic rimu_output o_{k};" for k in insts)
    stats_call = "rimu_step((rimu_real)(t - t0), (rimu_real)temp, " + \
        ", ".join(f"&s_{k}, y_{k}, v_{k}, &o_{k}" for k in insts) + ")"
    est = "\n".join(f"        put_est(est, &m_{k}, &f_{k}, {_prefix(k)}_N);" for k in insts)
    det = "\n".join(f"        put_detail(det, &m_{k}, &f_{k}, {_prefix(k)}_N);" for k in insts)
    head_est = ",".join(f"{k}_x,{k}_y,{k}_z,{k}_validity,{k}_isolated" for k in insts)
    head_det = ",".join(f"{k}_x,{k}_y,{k}_z,{k}_validity,{k}_isolated,{k}_state,{k}_alarm,{k}_statistic,{k}_dof,"
                        f"{k}_not_isolable,{k}_sensors" for k in insts)
    return f"""/* rimu_target.c -- generated by rimu (rimu.export.target): streams rimu_input.bin through rimu_fdi_step and
 * writes the estimates file (rimu_estimates.csv), the detail of every decision (rimu_detail.csv) and, on the
 * target, the SysTick ticks and stack bytes of every epoch (rimu_epochs.csv). Built for the Cortex-M4 (with
 * -DRIMU_CORTEX_M; files through semihosting) and for the desktop (files through the C library). */
#include <stdio.h>
#include "rimu_unit.h"
{_SYSTICK}
{decl}
#ifdef RIMU_STATS_ONLY
/* the projection and parity statistics only (rimu_step), no fault management: its instructions are counted, the
 * estimates and detail files are not its output */
{stats_decl}
#define RIMU_HARNESS_STEP {stats_call}
#else
#define RIMU_HARNESS_STEP {fdi_call}
#endif

static void put_est(FILE *f, const rimu_fdi *m, const rimu_fdi_output *o, int n)
{{
    int i, first = 1;
    fprintf(f, ",%.9g,%.9g,%.9g,%d,", (double)o->x[0], (double)o->x[1], (double)o->x[2], o->validity);
    for (i = 0; i < n; ++i) {{
        if (!m->iso[i]) continue;
        fprintf(f, first ? "%d" : ";%d", i);
        first = 0;
    }}
}}

static void put_detail(FILE *f, const rimu_fdi *m, const rimu_fdi_output *o, int n)
{{
    int i;
    put_est(f, m, o, n);
    fprintf(f, ",%d,%d,%.9g,%d,%d,", o->state, o->alarm, (double)o->statistic, o->dof, o->fault_not_isolable);
    for (i = 0; i < n; ++i) fprintf(f, i ? ";%d" : "%d", (int)m->sensor[i]);
}}

int main(void)
{{
    FILE *in = fopen("rimu_input.bin", "rb");
    FILE *est = fopen("rimu_estimates.csv", "w");
    FILE *det = fopen("rimu_detail.csv", "w");
    FILE *ep = fopen("rimu_epochs.csv", "w");
    double t, temp, t0 = 0.0;
    long row = 0;
    if (in == NULL || est == NULL || det == NULL || ep == NULL) {{
        fprintf(stderr, "rimu_target: cannot open rimu_input.bin or an output file\\n");
        return 2;
    }}
    tick_start();
    fprintf(ep, "calibration,%lu,%lu\\n", 100000ul, known_loop(100000ul));
    fprintf(ep, "epoch,ticks,stack_bytes\\n");
    fprintf(est, "t,{head_est}\\n");
    fprintf(det, "t,{head_det}\\n");
    for (;;) {{
        unsigned long a, b, used = 0u;
        int ok = fread(&t, sizeof t, 1, in) == 1 && fread(&temp, sizeof temp, 1, in) == 1;
{reads}
        if (!ok) break;
        if (row == 0) t0 = t;
#ifdef RIMU_CORTEX_M
        {{
            volatile unsigned long *top = (volatile unsigned long *)(sp_now() - 64u), *p;
            unsigned long k;
            for (k = 1u; k <= PAINT_WORDS; ++k) top[-(long)k] = PAINT;
            a = tick_now();
            {call}
            b = tick_now();
            for (k = PAINT_WORDS; k >= 1u; --k) {{
                p = top - k;
                if (*p != PAINT) break;
            }}
            used = (k == 0u) ? 0u : (unsigned long)(k * 4u + 64u);
        }}
#else
        a = tick_now();
        {call}
        b = tick_now();
#endif
        fprintf(ep, "%ld,%lu,%lu\\n", row, ticks(a, b), used);
        fprintf(est, "%.9g", t);
        fprintf(det, "%.9g", t);
{est}
{det}
        fprintf(est, "\\n");
        fprintf(det, "\\n");
        ++row;
    }}
    fclose(in);
    fclose(est);
    fclose(det);
    fclose(ep);
    return 0;
}}
"""


def _flight(cal: Calibration) -> str:
    insts = list(cal.instruments)
    decl = "\n".join(f"static volatile rimu_real y_{k}[{_prefix(k)}_N];\nstatic rimu_real yy_{k}[{_prefix(k)}_N];\n"
                     f"static unsigned char v_{k}[{_prefix(k)}_N];\nstatic rimu_fdi m_{k};\n"
                     f"static rimu_fdi_output f_{k};" for k in insts)
    copy = "\n".join(f"        for (i = 0; i < {_prefix(k)}_N; ++i) {{ yy_{k}[i] = y_{k}[i]; v_{k}[i] = 1u; }}"
                     for k in insts)
    call = "rimu_fdi_step(t, 20.0f, " + ", ".join(f"&m_{k}, yy_{k}, v_{k}, &f_{k}" for k in insts) + ");"
    return f"""/* rimu_flight.c -- generated by rimu (rimu.export.target): the smallest program that flies the unit (its
 * state, one rimu_fdi_step per epoch, no I/O); its link map gives the flash and RAM of the flight code. */
#include "rimu_unit.h"

{decl}
volatile rimu_real rimu_sink;

int main(void)
{{
    rimu_real t = 0.0f;
    int i;
    for (;;) {{
{copy}
        {call}
        rimu_sink = f_{insts[0]}.x[0];
        t += 0.01f;
    }}
}}
"""


_STARTUP = r"""/* rimu_m4_startup.c -- generated by rimu: vector table and reset handler of the mps2-an386 board (Cortex-M4F) */
extern unsigned long _sidata, _sdata, _edata, __bss_start__, __bss_end__, _estack;
extern int main(void);
extern void exit(int);
extern void initialise_monitor_handles(void) __attribute__((weak));
void Reset_Handler(void);
void Default_Handler(void);

void Default_Handler(void)
{
    for (;;) { }
}

void _init(void);
void _fini(void);
void _init(void) { }  /* no constructors: C only */
void _fini(void) { }

__attribute__((section(".vectors"), used))
static void (*const vectors[16])(void) = {
    (void (*)(void))&_estack, Reset_Handler, Default_Handler, Default_Handler, Default_Handler, Default_Handler,
    Default_Handler, 0, 0, 0, 0, Default_Handler, Default_Handler, 0, Default_Handler, Default_Handler
};

void Reset_Handler(void)
{
    unsigned long *s = &_sidata, *d = &_sdata;
    volatile unsigned long *cpacr = (volatile unsigned long *)0xE000ED88u;
    *cpacr |= 0xFu << 20;  /* CP10, CP11: the FPU, full access */
    __asm volatile ("dsb\n isb");
    while (d < &_edata) *d++ = *s++;
    for (d = &__bss_start__; d < &__bss_end__; ++d) *d = 0u;
    if (initialise_monitor_handles) initialise_monitor_handles();
    exit(main());
}
"""

_LINKER = """/* rimu_m4.ld -- generated by rimu: memory map of the mps2-an386 board (code at 0, data in SSRAM at 0x20000000) */
MEMORY
{
    FLASH (rx) : ORIGIN = 0x00000000, LENGTH = 4M
    RAM (rwx) : ORIGIN = 0x20000000, LENGTH = 4M
}
ENTRY(Reset_Handler)
SECTIONS
{
    .text : { KEEP(*(.vectors)) *(.text*) *(.rodata*) KEEP(*(.init)) KEEP(*(.fini)) . = ALIGN(4); } > FLASH
    .ARM.exidx : { *(.ARM.exidx*) } > FLASH
    .init_array : { KEEP(*(.init_array*)) } > FLASH
    .fini_array : { KEEP(*(.fini_array*)) } > FLASH
    _sidata = LOADADDR(.data);
    .data : { _sdata = .; *(.data*) . = ALIGN(4); _edata = .; } > RAM AT > FLASH
    .bss (NOLOAD) : { __bss_start__ = .; *(.bss*) *(COMMON) . = ALIGN(4); __bss_end__ = .; } > RAM
    end = .;
    _end = .;
    _estack = ORIGIN(RAM) + LENGTH(RAM);
}
"""

_MAKEFILE = """# generated by rimu (rimu.export.target): the Cortex-M4F build of this unit, its flight image and the desktop twin
CROSS ?= arm-none-eabi-
HOSTCC ?= cc
CPU = {cpu}
FP = {fp}
# -O3 with the sensor loops peeled completely (their count is a constant of the unit); GCC 12's
# -Wstringop-overflow misreads the peeled loops over RIMU_NMAX-sized arrays (a false positive), so it is off
OPT ?= -O3 --param max-completely-peeled-insns=2000 --param max-completely-peel-times=32 -fno-tree-loop-distribute-patterns
WARN = -std=c99 $(OPT) -Wall -Wextra -Werror -pedantic
TFLAGS = $(CPU) $(FP) $(WARN) -ffunction-sections -fdata-sections -DRIMU_CORTEX_M
LFLAGS = $(CPU) -nostartfiles -T rimu_m4.ld -Wl,--gc-sections
all: rimu_target.elf rimu_target_stats.elf rimu_flight.elf rimu_target_host
rimu_unit.o: rimu_unit.c rimu_unit.h
\t$(CROSS)gcc $(TFLAGS) -fstack-usage -fcallgraph-info=su -c rimu_unit.c -o $@
rimu_target.elf: rimu_target.c rimu_m4_startup.c rimu_unit.o rimu_m4.ld
\t$(CROSS)gcc $(TFLAGS) -Wno-pedantic -c rimu_target.c -o rimu_target.o
\t$(CROSS)gcc $(CPU) -O2 -Wall -Werror -c rimu_m4_startup.c -o rimu_m4_startup.o
\t$(CROSS)gcc $(LFLAGS) -specs=rdimon.specs -Wl,-Map=rimu_target.map -o $@ rimu_target.o rimu_m4_startup.o rimu_unit.o -lm
rimu_target_stats.elf: rimu_target.c rimu_target.elf rimu_unit.o
\t$(CROSS)gcc $(TFLAGS) -Wno-pedantic -DRIMU_STATS_ONLY -c rimu_target.c -o rimu_target_stats.o
\t$(CROSS)gcc $(LFLAGS) -specs=rdimon.specs -o $@ rimu_target_stats.o rimu_m4_startup.o rimu_unit.o -lm
rimu_flight.elf: rimu_flight.c rimu_target.elf rimu_unit.o rimu_m4.ld
\t$(CROSS)gcc $(TFLAGS) -c rimu_flight.c -o rimu_flight.o
\t$(CROSS)gcc $(LFLAGS) -specs=nosys.specs -Wl,-Map=rimu_flight.map -o $@ rimu_flight.o rimu_m4_startup.o rimu_unit.o -lm
rimu_target_host: rimu_target.c rimu_unit.c rimu_unit.h
\t$(HOSTCC) $(FP) $(WARN) -o $@ rimu_target.c rimu_unit.c -lm
clean:
\trm -f *.o *.su *.ci *.elf *.map rimu_target_host
"""


def _write(d: Path, name: str, text: str) -> Path:
    fd, tmp = tempfile.mkstemp(dir=d, prefix=f".{name}.")
    with os.fdopen(fd, "w") as fh:
        fh.write(text)
    os.chmod(tmp, 0o644)
    os.replace(tmp, d / name)
    return d / name


def write_target(calibration: Calibration, directory: str | os.PathLike[str],
                 fdi: FdiSettings | None = None) -> list[Path]:
    """Export ``calibration`` in single precision into ``directory`` and add the Cortex-M4 harness, flight image,
    startup code, linker script and ``Makefile.cortex-m4`` (module docstring). Returns the files written."""
    d = Path(directory)
    files = export_c(calibration, d, real="float", fdi=fdi)
    extra = {"rimu_target.c": _harness(calibration), "rimu_flight.c": _flight(calibration),
             "rimu_m4_startup.c": _STARTUP, "rimu_m4.ld": _LINKER,
             "Makefile.cortex-m4": _MAKEFILE.format(cpu=" ".join(CPU_FLAGS), fp=" ".join(FP_FLAGS))}
    return files + [_write(d, name, text) for name, text in extra.items()]


def build_target(directory: str | os.PathLike[str]) -> subprocess.CompletedProcess:
    """``make -f Makefile.cortex-m4`` in an exported ``directory``. Raises :class:`ExportError` naming the tools
    that are missing."""
    from ..atomic import flush_outputs

    flush_outputs()  # a command's held-back outputs are what this reads: in place

    miss = missing_tools()
    if miss:
        raise ExportError(f"the Cortex-M4 build needs {', '.join(miss)} (Debian: apt-get install gcc-arm-none-eabi "
                          "libnewlib-arm-none-eabi qemu-system-arm make gcc)")
    cc = next(c for c in ("cc", "gcc", "clang") if shutil.which(c))
    return subprocess.run(["make", "-s", "-f", "Makefile.cortex-m4", f"HOSTCC={cc}"], cwd=Path(directory),
                          capture_output=True, text=True)


@dataclass
class TargetRun:
    """What one run of the harness wrote: the estimates file and the detail (CSV text), and on the target the
    SysTick ticks and stack bytes of each epoch and the instructions per tick measured on a known loop."""

    estimates: str
    detail: str
    ticks: np.ndarray
    stack: np.ndarray
    insn_per_tick: float

    @property
    def instructions(self) -> np.ndarray:
        """Instructions of each epoch's ``rimu_fdi_step`` (ticks times the measured instructions per tick)."""
        return self.ticks * self.insn_per_tick


def run_target(directory: str | os.PathLike[str], input_path: str | os.PathLike[str], host: bool = False,
               timeout: float = 120.0, stats_only: bool = False) -> TargetRun:
    """Stream ``input_path`` (:func:`write_input`) through the built harness: under ``qemu-system-arm -M
    mps2-an386 -icount shift=0`` with semihosting (or the desktop twin with ``host=True``), in a scratch folder
    beside ``directory``. ``stats_only``: the harness that runs ``rimu_step`` (projection and parity statistics,
    no fault management; only its instruction counts mean something)."""
    from ..atomic import flush_outputs

    flush_outputs()  # a command's held-back outputs are what this reads: in place

    d = Path(directory).resolve()
    with tempfile.TemporaryDirectory(dir=d) as w:
        wd = Path(w)
        shutil.copyfile(input_path, wd / "rimu_input.bin")
        if host:
            cmd = [str(d / "rimu_target_host")]
        else:
            cmd = ["qemu-system-arm", "-M", QEMU_BOARD, "-cpu", "cortex-m4", "-nographic", "-monitor", "none",
                   "-serial", "none", "-icount", "shift=0", "-semihosting-config", "enable=on,target=native",
                   "-kernel", str(d / ("rimu_target_stats.elf" if stats_only else "rimu_target.elf"))]
        res = subprocess.run(cmd, cwd=wd, capture_output=True, text=True, timeout=timeout)
        if res.returncode != 0:
            raise ExportError(f"the harness failed ({' '.join(cmd[:1])}, status {res.returncode}): "
                              f"{(res.stderr or res.stdout).strip()[:400]}")
        ep = (wd / "rimu_epochs.csv").read_text().splitlines()
        cal_n, cal_ticks = (int(v) for v in ep[0].split(",")[1:])
        rows = np.array([[int(v) for v in ln.split(",")] for ln in ep[2:]], dtype=np.int64).reshape(-1, 3)
        ipt = 2.0 * cal_n / cal_ticks if cal_ticks else float("nan")
        return TargetRun((wd / "rimu_estimates.csv").read_text(), (wd / "rimu_detail.csv").read_text(),
                         rows[:, 1].astype(float), rows[:, 2].astype(float), ipt)
