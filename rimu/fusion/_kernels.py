"""Compiled kernels of the runtime pipeline (numba), the optional ``fast`` backend (``pip install rimu[fast]``).

The same arithmetic as the numpy reference (:mod:`rimu.fusion.pipeline`, :mod:`rimu.fusion.effects`), written as
loops over the sensors so that one call does a whole sample (or a whole block) without Python in between:

* :func:`project_one`, :func:`project_block`: ``out = R y - off`` on the current active set, with the range and
  finiteness checks of the fast path (Cho & Park 2005, Eq. 20; de Oliveira Eq. 11 for the parity rows);
* :func:`epoch_step`, :func:`epoch_block`: the compensation of every further effect (exogenous error = a matrix
  times the epoch's monomials; output-side effects inverted by Newton per sensor with the cross coupling from the
  instrument's estimate; the gyro <-> accelerometer fixed point) followed by the projection, for every
  instrument of the unit, in the pipeline's order.

Every kernel returns whether it could do the whole sample (block) on the common path: every value finite and
within range, every sensor valid, the active set observable. When it could not, the caller runs the numpy
reference instead, which routes around what is missing; a kernel never changes the pipeline's state.

The compensation stage of a unit is described by two arrays that :class:`Program` builds once
(``F``: every coefficient, ``L``: sizes, flags and offsets into F); the active sets' G, R, off are copied into F
when a set changes (never per sample). Kernels are compiled on first use and cached on disk (``cache=True``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

try:
    import numba
except ImportError as exc:  # pragma: no cover - the caller checks availability first
    raise ImportError("the compiled backend needs numba: pip install rimu[fast]") from exc

__all__ = ["BlockPath", "Program", "block_kernel", "epoch_block", "epoch_step", "project_block", "project_one"]

#: IEEE arithmetic as numpy's (error_model="numpy": x / 0 is inf or nan, not an exception); no fast-math.
#: No reference counting (``_nrt=False``): the kernels allocate nothing, and with NRT every call of a helper
#: increfs and decrefs its array arguments with atomic instructions, which cost more than the per-sample
#: arithmetic of a small unit (about 0.15 us of every sample of the all-effects epoch on cone6)
_jit = numba.njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
#: the helpers of the compensation are inlined into :func:`_epoch` (numba IR inlining: LLVM does not inline them,
#: and a call passes every array as a struct of seven words); :func:`_epoch` calls :func:`_solve` from one place,
#: so that its code, the longest, appears once; :func:`_epoch` itself stays one function that both epoch kernels
#: call (one call per epoch; inlining it into both doubled the compile time for no measurable gain)
_inline = numba.njit(cache=True, nogil=True, error_model="numpy", _nrt=False, inline="always")

#: index cast: an unsigned index needs no negative-index wraparound check (numba adds one to every signed index
#: whose sign it cannot prove, which costs half the speed of these loops); every index here is >= 0
_u = numba.uint64

#: monomials of an epoch (rimu.calibration.model.MONOMIALS): 1, t, dT, dT^2, f, f pairs, w, w pairs
M = 22
#: coefficient blocks of the compensation (rows of 5 n x M): exogenous error, k1, k2, k3, k_abs
B_EXO, B_K1, B_K2, B_K3, B_KA = 0, 1, 2, 3, 4

# layout of L: a header, then one record per instrument slot (in the pipeline's order)
H_NSLOT, H_CYCLIC, H_ROUNDS, H_ACC, H_GYR, H_WORK, H_SIZE = 0, 1, 2, 3, 4, 5, 8
S_N, S_M, S_MODE, S_KIND, S_OUT, S_NEEDU, S_STEPS, S_SCALE, S_BIAS, S_RANGE, S_C, S_HX, S_H, S_G, S_R, S_OFF, \
    S_OBS, S_PRESENT, S_DYN, S_RAWEXO, S_COLS, S_WY, S_WRAW, S_WOUT = range(24)
S_SIZE = 24
MODE_NONE, MODE_RAWEXO, MODE_FULL = 0, 1, 2
KIND_ACC, KIND_GYR = 0, 1


# ---------------------------------------------------------------------------------------------- projection
@_jit
def project_one(y: Any, R: Any, off: Any, rng: Any, out: Any) -> bool:  # pragma: no cover - compiled
    """``out = R y - off`` for one sample; False (out unspecified) when a value is non-finite or at its range."""
    n = R.shape[1]
    if y.shape[0] != n:
        return False
    for i in range(n):
        if not abs(y[_u(i)]) < rng[_u(i)]:
            return False
    s = 0.0
    for j in range(R.shape[0]):
        acc = 0.0
        for i in range(n):
            acc += R[_u(j), _u(i)] * y[_u(i)]
        acc -= off[_u(j)]
        out[_u(j)] = acc
        s += acc
    return s - s == 0.0


@_jit
def project_block(Y: Any, R: Any, off: Any, rng: Any, out: Any) -> bool:  # pragma: no cover - compiled
    """:func:`project_one` on every row of Y (N, n) into out (N, m); False as soon as a row is not clean."""
    n = R.shape[1]
    m = R.shape[0]
    for k in range(Y.shape[0]):
        for i in range(n):
            if not abs(Y[_u(k), _u(i)]) < rng[_u(i)]:
                return False
        s = 0.0
        for j in range(m):
            acc = 0.0
            for i in range(n):
                acc += R[_u(j), _u(i)] * Y[_u(k), _u(i)]
            acc -= off[_u(j)]
            out[_u(k), _u(j)] = acc
            s += acc
        if not s - s == 0.0:
            return False
    return True


# ---------------------------------------------------------------------------------------------- compensation
# Everything below works on offsets into the one scratch array W (no views, no allocation per sample):
# W[0:M] monomials, then f (3), w (3), u (3), then per slot its raw input y, its compensated raw output, its
# output (x, parity), and one work area (q, z, q', the 5 coefficient blocks: 8 n_max).
W_MONO, W_F, W_W, W_U = 0, M, M + 3, M + 6


@_inline
def _monomials(t: float, dT: float, have_f: bool, have_w: bool, W: Any) -> None:  # pragma: no cover - compiled
    """rimu.fusion.effects._monomials_one of (t, dT, f = W[W_F:], w = W[W_W:]) into W[0:M]; absent as zeros."""
    W[_u(0)] = 1.0
    W[_u(1)] = t
    W[_u(2)] = dT
    W[_u(3)] = dT * dT
    for b in range(2):
        j = 4 + 9 * b
        v = W_F if b == 0 else W_W
        if have_f if b == 0 else have_w:
            x, y, z = W[_u(v)], W[_u(v + 1)], W[_u(v + 2)]
            W[_u(j)], W[_u(j + 1)], W[_u(j + 2)] = x, y, z
            W[_u(j + 3)], W[_u(j + 4)], W[_u(j + 5)] = x * x, x * y, x * z
            W[_u(j + 6)], W[_u(j + 7)], W[_u(j + 8)] = y * y, y * z, z * z
        else:
            for a in range(9):
                W[_u(j + a)] = 0.0


@_inline
def _coefs(F: Any, L: Any, base: int, W: Any, k0: int) -> None:  # pragma: no cover - compiled
    """Coefficients of every present block for every sensor into W[k0:k0 + 5 n]: each row of C times the
    monomials it uses, in the order of the monomials (EffectCompensation._coefficient_arrays; only the constant
    where a block does not vary). C is stored (block, monomial, sensor): the sensors' sums run side by side."""
    n = L[_u(base + S_N)]
    present = L[_u(base + S_PRESENT)]
    dyn = L[_u(base + S_DYN)]
    cols = L[_u(base + S_COLS)]
    c_base = L[_u(base + S_C)]
    for blk in range(5):
        nc = L[_u(cols)]
        cols += 1
        if (present >> blk) & 1:
            c0 = c_base + blk * M * n
            o = k0 + blk * n
            for i in range(n):
                W[_u(o + i)] = F[_u(c0 + i)]
            if (dyn >> blk) & 1:
                for a in range(nc):
                    j = L[_u(cols + a)]
                    mj = W[_u(j)]
                    cj = c0 + j * n
                    for i in range(n):
                        W[_u(o + i)] += F[_u(cj + i)] * mj
        cols += nc


@_inline
def _estimate(F: Any, L: Any, base: int, W: Any, q0: int, u0: int) -> bool:  # pragma: no cover - compiled
    """MB estimate W[u0:u0+3] = G q on the current set (InstrumentPipeline.estimate); False if q is not finite."""
    n = L[_u(base + S_N)]
    g0 = L[_u(base + S_G)]
    s = 0.0
    for i in range(n):
        s += W[_u(q0 + i)]
    if not s - s == 0.0:
        return False
    for j in range(3):
        acc = 0.0
        for i in range(n):
            acc += F[_u(g0 + j * n + i)] * W[_u(q0 + i)]
        W[_u(u0 + j)] = acc
    return True


@_inline
def _solve(F: Any, L: Any, base: int, W: Any) -> bool:  # pragma: no cover - compiled
    """EffectCompensation.solve_one of the slot's input y: the effect-free outputs q into the work area
    (Newton on each sensor's own input, the cross coupling from the estimate); False if not finite."""
    n = L[_u(base + S_N)]
    sc = L[_u(base + S_SCALE)]
    bi = L[_u(base + S_BIAS)]
    y0 = L[_u(base + S_WY)]
    q0 = L[_u(H_WORK)]
    z0 = q0 + n
    n0 = z0 + n
    k0 = n0 + n
    present = L[_u(base + S_PRESENT)]
    _coefs(F, L, base, W, k0)
    for i in range(n):
        z = W[_u(y0 + i)] * F[_u(sc + i)] - F[_u(bi + i)]
        if present & 1:
            z = z - W[_u(k0 + i)]
        W[_u(z0 + i)] = z
        W[_u(q0 + i)] = z
    if not L[_u(base + S_OUT)]:
        return True
    needs_u = L[_u(base + S_NEEDU)]
    hx = L[_u(base + S_HX)]
    h0 = L[_u(base + S_H)]
    has1, has2, has3, hasa = (present >> 1) & 1, (present >> 2) & 1, (present >> 3) & 1, (present >> 4) & 1
    u0 = W_U
    for _ in range(L[_u(base + S_STEPS)]):
        if needs_u:
            if not _estimate(F, L, base, W, q0, u0):
                return False
        for i in range(n):
            s = W[_u(q0 + i)]
            lin = W[_u(k0 + B_K1 * n + i)] if has1 else 0.0
            if has3:
                a = W[_u(k0 + B_K3 * n + i)] * s
                if has2:
                    k2 = W[_u(k0 + B_K2 * n + i)]
                    quad = a + k2
                    slope2 = 2.0 * k2 + 3.0 * a
                else:
                    quad = a
                    slope2 = 3.0 * a
            elif has2:
                k2 = W[_u(k0 + B_K2 * n + i)]
                quad = k2
                slope2 = 2.0 * k2
            else:
                quad = 0.0
                slope2 = 0.0
            c = (lin + quad * s) * s
            dc = lin + slope2 * s
            if hasa:
                ka = W[_u(k0 + B_KA * n + i)]
                c = c + ka * abs(s)
                dc = dc + ka * (1.0 if s > 0.0 else (-1.0 if s < 0.0 else 0.0 * s))
            if needs_u:
                hu = F[_u(h0 + 3 * i)] * W[_u(u0)] + F[_u(h0 + 3 * i + 1)] * W[_u(u0 + 1)] + F[_u(h0 + 3 * i + 2)] * W[_u(u0 + 2)]
                xu = F[_u(hx + 3 * i)] * W[_u(u0)] + F[_u(hx + 3 * i + 1)] * W[_u(u0 + 1)] + F[_u(hx + 3 * i + 2)] * W[_u(u0 + 2)]
                c = c + hu * xu
            W[_u(n0 + i)] = s - (s + c - W[_u(z0 + i)]) / (1.0 + dc)
        for i in range(n):
            W[_u(q0 + i)] = W[_u(n0 + i)]
    return True


@_inline
def _raw(F: Any, L: Any, base: int, W: Any) -> None:  # pragma: no cover - compiled
    """EffectCompensation.raw_one: the raw outputs of an ideal scale/misalignment/bias sensor into the slot's raw
    area; for a slot that inverts output-side effects, from the effect-free outputs :func:`_solve` left in the
    work area."""
    n = L[_u(base + S_N)]
    mode = L[_u(base + S_MODE)]
    y0 = L[_u(base + S_WY)]
    r0 = L[_u(base + S_WRAW)]
    if mode == MODE_NONE:
        for i in range(n):
            W[_u(r0 + i)] = W[_u(y0 + i)]
    elif mode == MODE_RAWEXO:  # y - E mono / SF, E stored (monomial, sensor): the sensors' sums side by side
        e0 = L[_u(base + S_RAWEXO)]
        cols = L[_u(base + S_COLS)]  # the exogenous block's monomials come first
        for i in range(n):
            W[_u(r0 + i)] = F[_u(e0 + i)]
        for a in range(L[_u(cols)]):
            j = L[_u(cols + 1 + a)]
            mj = W[_u(j)]
            ej = e0 + j * n
            for i in range(n):
                W[_u(r0 + i)] += F[_u(ej + i)] * mj
        for i in range(n):
            W[_u(r0 + i)] = W[_u(y0 + i)] - W[_u(r0 + i)]
    else:
        sc = L[_u(base + S_SCALE)]
        bi = L[_u(base + S_BIAS)]
        q0 = L[_u(H_WORK)]
        for i in range(n):
            W[_u(r0 + i)] = (W[_u(q0 + i)] + F[_u(bi + i)]) / F[_u(sc + i)]


@_inline
def _project(F: Any, L: Any, base: int, W: Any) -> bool:  # pragma: no cover - compiled
    """InstrumentPipeline.step's common path on the compensated raw sample: range, R raw - off, finiteness."""
    n = L[_u(base + S_N)]
    m = L[_u(base + S_M)]
    if not L[_u(base + S_OBS)]:
        return False
    rg = L[_u(base + S_RANGE)]
    x0 = L[_u(base + S_WRAW)]
    for i in range(n):
        if not abs(W[_u(x0 + i)]) < F[_u(rg + i)]:
            return False
    r0 = L[_u(base + S_R)]
    o0 = L[_u(base + S_OFF)]
    w0 = L[_u(base + S_WOUT)]
    s = 0.0
    for j in range(m):
        acc = 0.0
        for i in range(n):
            acc += F[_u(r0 + j * n + i)] * W[_u(x0 + i)]
        acc -= F[_u(o0 + j)]
        W[_u(w0 + j)] = acc
        s += acc
    return s - s == 0.0


@_jit
def _epoch(F: Any, L: Any, W: Any, t: float, dT: float) -> bool:  # pragma: no cover - compiled
    """Pipeline.step of one epoch whose raw samples are in W: compensation of every instrument (with the fixed
    point where the gyros need the specific force and the accelerometers the rate), then the projection, in
    the pipeline's order; outputs into W.

    One loop over the stages of the epoch: first the rounds of the fixed point (accelerometers, then gyros, each
    solved and estimated), then every slot (compensated and projected)."""
    if not (t - t == 0.0 and dT - dT == 0.0):  # the numpy path makes every output invalid
        return False
    have_f = False
    have_w = False
    cycle = 2 * L[_u(H_ROUNDS)] if L[_u(H_CYCLIC)] else 0
    q0 = L[_u(H_WORK)]
    if cycle:
        for a in range(3):
            W[_u(W_W + a)] = 0.0
    for stage in range(cycle + L[_u(H_NSLOT)]):
        if stage < cycle:
            acc = stage % 2 == 0
            base = H_SIZE + S_SIZE * (L[_u(H_ACC)] if acc else L[_u(H_GYR)])
            _monomials(t, dT, not acc, acc, W)
            mode = MODE_FULL
        else:
            base = H_SIZE + S_SIZE * (stage - cycle)
            mode = L[_u(base + S_MODE)]
            if mode != MODE_NONE:
                _monomials(t, dT, have_f, have_w, W)
        if mode == MODE_FULL and not _solve(F, L, base, W):
            return False
        if stage < cycle:
            if not _estimate(F, L, base, W, q0, W_F if acc else W_W):
                return False
            if stage == cycle - 1:
                have_w = True
            continue
        _raw(F, L, base, W)
        if not _project(F, L, base, W):
            return False
        w0 = L[_u(base + S_WOUT)]
        v = W_F if L[_u(base + S_KIND)] == KIND_ACC else W_W
        W[_u(v)], W[_u(v + 1)], W[_u(v + 2)] = W[_u(w0)], W[_u(w0 + 1)], W[_u(w0 + 2)]
        if L[_u(base + S_KIND)] == KIND_ACC:
            have_f = True
        else:
            have_w = True
    return True


@_jit
def epoch_step(F: Any, L: Any, W: Any, y0: Any, y1: Any, t: float, dT: float, out0: Any,
               out1: Any) -> bool:  # pragma: no cover - compiled
    """One epoch (Pipeline.step); outputs (x, parity) into out0/out1 (the instrument pipelines' buffers)."""
    nslot = L[_u(H_NSLOT)]
    for s in range(nslot):
        base = H_SIZE + S_SIZE * s
        y = y0 if s == 0 else y1
        n = L[_u(base + S_N)]
        if y.shape[0] != n:
            return False
        a = L[_u(base + S_WY)]
        for i in range(n):
            W[_u(a + i)] = y[_u(i)]
    if not _epoch(F, L, W, t, dT):
        return False
    for s in range(nslot):
        base = H_SIZE + S_SIZE * s
        out = out0 if s == 0 else out1
        w0 = L[_u(base + S_WOUT)]
        for j in range(L[_u(base + S_M)]):
            out[_u(j)] = W[_u(w0 + j)]
    return True


@_jit
def epoch_block(F: Any, L: Any, W: Any, Y0: Any, Y1: Any, t: Any, dT: Any, O0: Any, O1: Any, R0: Any, R1: Any,
                want_raw: bool) -> int:  # pragma: no cover - compiled
    """Every epoch of a block (Pipeline.process); -1 when all were clean, else the first row that was not.
    Outputs into O0/O1 (N, m); the compensated raw outputs into R0/R1 (N, n) when ``want_raw``."""
    nslot = L[_u(H_NSLOT)]
    for k in range(Y0.shape[0]):
        for s in range(nslot):
            base = H_SIZE + S_SIZE * s
            a = L[_u(base + S_WY)]
            if s == 0:
                for i in range(L[_u(base + S_N)]):
                    W[_u(a + i)] = Y0[_u(k), _u(i)]
            else:
                for i in range(L[_u(base + S_N)]):
                    W[_u(a + i)] = Y1[_u(k), _u(i)]
        if not _epoch(F, L, W, t[k], dT[k]):
            return k
        for s in range(nslot):
            base = H_SIZE + S_SIZE * s
            w0 = L[_u(base + S_WOUT)]
            r0 = L[_u(base + S_WRAW)]
            if s == 0:
                for j in range(L[_u(base + S_M)]):
                    O0[_u(k), _u(j)] = W[_u(w0 + j)]
                if want_raw:
                    for i in range(L[_u(base + S_N)]):
                        R0[_u(k), _u(i)] = W[_u(r0 + i)]
            else:
                for j in range(L[_u(base + S_M)]):
                    O1[_u(k), _u(j)] = W[_u(w0 + j)]
                if want_raw:
                    for i in range(L[_u(base + S_N)]):
                        R1[_u(k), _u(i)] = W[_u(r0 + i)]
    return -1


# ---------------------------------------------------------------------------------------------- the program
class Program:
    """The compensation stage of a unit as two arrays for :func:`epoch_step` / :func:`epoch_block`.

    Parameters
    ----------
    slots : list of (kind, EffectCompensation or None, InstrumentPipeline)
        Instruments in the pipeline's order (at most two); kind ``"gyro"`` or ``"accel"``.
    cyclic : bool, rounds : int
        The gyro <-> accelerometer fixed point and its rounds (``Pipeline.cycle_rounds``).
    """

    def __init__(self, slots: list[tuple[str, Any, Any]], cyclic: bool, rounds: int) -> None:
        if not 1 <= len(slots) <= 2:
            raise ValueError("the compiled stage handles one or two instruments")
        L = np.zeros(H_SIZE + S_SIZE * len(slots), dtype=np.int64)
        L[H_NSLOT] = len(slots)
        L[H_CYCLIC] = int(cyclic)
        L[H_ROUNDS] = self.rounds = int(rounds)
        chunks: list[np.ndarray] = []
        pos = 0

        def put(a: np.ndarray) -> int:
            nonlocal pos
            a = np.ascontiguousarray(a, dtype=float).reshape(-1)
            chunks.append(a)
            start = pos
            pos += a.size
            return start

        self.pipes = []
        self._sets: list[Any] = []
        extra: list[int] = []
        n_max = 1
        for s, (kind, comp, pipe) in enumerate(slots):
            b = H_SIZE + S_SIZE * s
            n = pipe.n
            n_max = max(n_max, n)
            L[b + S_N] = n
            L[b + S_M] = 3 + pipe.r
            L[b + S_KIND] = KIND_ACC if kind == "accel" else KIND_GYR
            if kind == "accel":
                L[H_ACC] = s
            else:
                L[H_GYR] = s
            cal = pipe.calibration
            L[b + S_SCALE] = put(cal.scale)
            L[b + S_BIAS] = put(cal.bias)
            L[b + S_RANGE] = put(pipe._range)
            L[b + S_G] = put(np.zeros((3, n)))
            L[b + S_R] = put(np.zeros((3 + pipe.r, n)))
            L[b + S_OFF] = put(np.zeros(3 + pipe.r))
            C = np.zeros((5, n, M))
            present = dyn = 0
            if comp is None:
                L[b + S_MODE] = MODE_NONE
            else:
                keys = {"exo": B_EXO, 1: B_K1, 2: B_K2, 3: B_K3, "abs": B_KA}
                for key, blk in keys.items():
                    if key in comp._const:
                        C[blk, :, 0] = comp._const[key]
                        present |= 1 << blk
                for j, key in enumerate(comp._dyn_keys):
                    blk = keys[key]
                    C[blk] = comp._dyn[j * n:(j + 1) * n]
                    present |= 1 << blk
                    dyn |= 1 << blk
                if comp._raw_exo is not None:
                    L[b + S_MODE] = MODE_RAWEXO
                    L[b + S_RAWEXO] = put(comp._raw_exo.T)  # (monomial, sensor)
                else:
                    L[b + S_MODE] = MODE_FULL
                L[b + S_OUT] = int(bool(comp.output_side))
                L[b + S_NEEDU] = int(comp._Hx is not None)
                L[b + S_STEPS] = comp.newton_steps
                L[b + S_HX] = put(comp._Hx if comp._Hx is not None else np.zeros((n, 3)))
                L[b + S_H] = put(comp._H)
            L[b + S_C] = put(C.transpose(0, 2, 1))  # (block, monomial, sensor)
            L[b + S_PRESENT] = present
            L[b + S_DYN] = dyn
            L[b + S_COLS] = len(L) + len(extra)
            for blk in range(5):  # per block: how many monomials it varies with, and which
                used = [j for j in range(1, M) if np.any(C[blk, :, j])]
                extra += [len(used), *used]
            self.pipes.append(pipe)
            self._sets.append(None)
        self.F = np.concatenate(chunks) if chunks else np.zeros(0)
        self.L = np.concatenate([L, np.array(extra, dtype=np.int64)])
        self.n_max = n_max
        wpos = M + 9
        for s in range(len(slots)):  # the slot's raw input, compensated raw output and output in W
            b = H_SIZE + S_SIZE * s
            n, m = self.L[b + S_N], self.L[b + S_M]
            self.L[b + S_WY], self.L[b + S_WRAW], self.L[b + S_WOUT] = wpos, wpos + n, wpos + 2 * n
            wpos += 2 * n + m
        self.L[H_WORK] = wpos
        self.W = np.zeros(wpos + 8 * n_max)
        self.refresh()

    def refresh(self) -> None:
        """Copy the current active set of every instrument into F (when it changed)."""
        F, L = self.F, self.L
        for s, pipe in enumerate(self.pipes):
            st = pipe._set
            if st is self._sets[s]:
                continue
            b = H_SIZE + S_SIZE * s
            n, m = pipe.n, 3 + pipe.r
            F[L[b + S_G]:L[b + S_G] + 3 * n] = st.G.reshape(-1)
            F[L[b + S_R]:L[b + S_R] + m * n] = st.R.reshape(-1)
            F[L[b + S_OFF]:L[b + S_OFF] + m] = st.off
            L[b + S_OBS] = int(st.observable)
            self._sets[s] = st

    def changed(self) -> bool:
        """Whether some instrument's active set changed since the last :meth:`refresh`."""
        for s, pipe in enumerate(self.pipes):
            if pipe._set is not self._sets[s]:
                return True
        return False


# ---------------------------------------------------------------------------------------------- the block path
#: largest n * m of an instrument whose block path is compiled, written out in full (every coefficient a local,
#: every loop unrolled: the C a programmer writes for one unit); larger instruments take numpy's BLAS product,
#: which is as fast there (a 24-axis instrument is 576 multiply-adds a sample)
UNROLL_MAX = 400
#: bound on the raw inputs beyond which the block path hands the block to numpy: with every |y_i| below
#: ``_SAFE / (1 + max_j sum_i |R_ji|)`` and every |off_j| below ``_SAFE``, no output can overflow, so a block whose
#: inputs pass the range test needs no finiteness test of its outputs
_SAFE = 1e300


def _block_source(sizes: tuple[tuple[int, int], ...]) -> str:
    """Python source of :func:`block_kernel` for instruments of sizes ``(n, m)``.

    The kernel ``k(Y0, [Y1,] P, O0, [O1])`` does ``O = Y @ R.T - off`` for every instrument of a unit in one pass
    and returns 0 when every raw value was finite and inside its limit, 1 when some was not (outputs unspecified),
    2 when the shapes do not agree (an empty block, a block whose column count is not the instrument's, or an output
    buffer of another shape; nothing written): the caller's checks are the kernel's. The range test is a maximum of
    the bit patterns of ``|y|`` (monotone in ``|y|`` for non-negative doubles; NaN's pattern is above inf's), an
    integer reduction that the compiler vectorises, compared with the limits once per block. ``P`` packs, per
    instrument, ``R`` (m, n) row-major, ``off`` (m) and the limits (n) (:meth:`BlockPath.pack`)."""
    k = len(sizes)
    args = [f"Y{s}" for s in range(k)] + ["P"] + [f"O{s}" for s in range(k)]
    shape = " or ".join(f"Y{s}.shape[0] != N or Y{s}.shape[1] != {n} or O{s}.shape[0] != N or O{s}.shape[1] != {m}"
                        for s, (n, m) in enumerate(sizes))
    L = [f"def kernel({', '.join(args)}):", "    N = Y0.shape[0]", f"    if N == 0 or {shape}:", "        return 2",
         "    Pb = P.view(np.int64)"]
    tail: list[str] = []
    pos = 0
    for s, (n, m) in enumerate(sizes):
        L += [f"    y{s} = Y{s}.reshape(N * {n})", f"    yb{s} = y{s}.view(np.int64)", f"    o{s} = O{s}.reshape(N * {m})"]
        lim = pos + m * n + m
        for j in range(m):
            L.append("    " + ", ".join(f"r{s}_{j}_{i}" for i in range(n)) + ", = "
                     + ", ".join(f"P[{pos + j * n + i}]" for i in range(n)) + ",")
            L.append(f"    f{s}_{j} = P[{pos + m * n + j}]")
        L.append("    " + ", ".join(f"a{s}_{i}" for i in range(n)) + ", = " + ", ".join("np.int64(0)" for _ in range(n))
                 + ",")
        body = ["    for k in range(N):", f"        b = u(k * {n})", f"        c = u(k * {m})"]
        for i in range(n):
            body.append(f"        y{s}_{i} = y{s}[b + u({i})]")
            body.append(f"        a{s}_{i} = max(a{s}_{i}, yb{s}[b + u({i})] & MASK)")
        for j in range(m):
            body.append(f"        o{s}[c + u({j})] = " + " + ".join(f"r{s}_{j}_{i} * y{s}_{i}" for i in range(n))
                        + f" - f{s}_{j}")
        tail += [f"a{s}_{i} < Pb[{lim + i}]" for i in range(n)]
        L += body  # one loop per instrument: its coefficients stay in registers
        pos = lim + n
    L.append("    return 0 if " + " and ".join(tail) + " else 1")
    return "\n".join(L) + "\n"


_BLOCK_KERNELS: dict[tuple[tuple[int, int], ...], Any] = {}


def block_kernel(sizes: tuple[tuple[int, int], ...]) -> Any:
    """The compiled block path of instruments of sizes ``((n, m), ...)`` (one or two), its sizes fixed at compile
    time (:func:`_block_source`); compiled once per process for each set of sizes, and cached on disk where the
    generated source can be written (``NUMBA_CACHE_DIR``, else the user's cache directory)."""
    sizes = tuple((int(n), int(m)) for n, m in sizes)
    fn = _BLOCK_KERNELS.get(sizes)
    if fn is not None:
        return fn
    src = "import numpy as np\nimport numba\n\nMASK = np.int64(0x7FFFFFFFFFFFFFFF)\nu = numba.uint64\n\n\n" \
        + _block_source(sizes)
    name = "rimu_block_" + "_".join(f"{n}x{m}" for n, m in sizes) + f"_v2_{UNROLL_MAX}"
    # one signature, compiled now: C-ordered, writable float64 blocks and buffers; numba's dispatcher refuses
    # anything else (another dtype or layout, a read-only block, not an array) with a TypeError, which is the
    # caller's cue to convert (BlockPath.run) -- no per-call checks of type, dtype or layout in Python
    a2, a1 = numba.types.Array(numba.float64, 2, "C"), numba.types.Array(numba.float64, 1, "C")
    sig = numba.int64(*([a2] * len(sizes) + [a1] + [a2] * len(sizes)))
    ns: dict[str, Any] = {}
    try:
        import importlib.util
        import os
        import sys
        from pathlib import Path
        root = os.environ.get("NUMBA_CACHE_DIR") or os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
        d = Path(root) / "rimu" / "kernels"
        d.mkdir(parents=True, exist_ok=True)
        f = d / f"{name}.py"
        if not f.exists() or f.read_text() != src:
            tmp = f.with_suffix(f".{os.getpid()}.tmp")
            tmp.write_text(src)
            os.replace(tmp, f)
        spec = importlib.util.spec_from_file_location(name, f)
        mod = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
        spec.loader.exec_module(mod)  # type: ignore[union-attr]
        sys.modules[name] = mod  # numba's disk cache finds the function's module by name
        fn = numba.njit(sig, cache=True, nogil=True, error_model="numpy", _nrt=False)(mod.kernel)
    except OSError:  # nowhere to write: compiled in memory, every process
        exec(compile(src, f"<{name}>", "exec"), ns)  # the source above: made from two integers per instrument
        fn = numba.njit(sig, nogil=True, error_model="numpy", _nrt=False)(ns["kernel"])
    _BLOCK_KERNELS[sizes] = fn
    return fn


class BlockPath:
    """The compiled block path of instrument pipelines (one, or a unit's two): ``out = Y @ R.T - off`` on each
    one's current active set (Cho & Park 2005, Eq. 20 folded into R and off; de Oliveira 2012, Eq. 11 for the
    parity rows), with the range and finiteness test, for every block length, in one call.

    The kernel's coefficients are packed when an active set changes (never per block); :meth:`run` returns 1
    (outputs unspecified) when some raw value is non-finite, at its range or too large to project without overflow,
    and the caller then runs the numpy path, which routes around it (2 when the shapes disagree: the numpy path
    says what is wrong).
    """

    def __init__(self, pipes: list[Any]) -> None:
        self.pipes = pipes
        self.sizes = tuple((p.n, 3 + p.r) for p in pipes)
        self.kernel = block_kernel(self.sizes)
        self.P = np.zeros(sum(m * n + m + n for n, m in self.sizes))
        #: the active set of each instrument that P holds
        self.sets: list[Any] = [None] * len(pipes)

    def pack(self) -> None:
        """Copy every instrument's current R, off and input limit into P."""
        pos = 0
        for s, (p, (n, m)) in enumerate(zip(self.pipes, self.sizes)):
            st = p._set
            R = np.asarray(st.R, dtype=float)
            off = np.asarray(st.off, dtype=float)
            self.P[pos:pos + m * n] = R.reshape(-1)
            self.P[pos + m * n:pos + m * n + m] = off
            lim = np.minimum(p._range, _SAFE / (1.0 + float(np.abs(R).sum(axis=1).max())))
            if not st.observable or not np.all(np.abs(off) < _SAFE):
                lim = np.zeros(n)  # every block to the numpy path
            self.P[pos + m * n + m:pos + m * n + m + n] = lim
            pos += m * n + m + n
            self.sets[s] = st

    def current(self) -> bool:
        """Whether P holds every instrument's current active set (else :meth:`pack`)."""
        for p, st in zip(self.pipes, self.sets):
            if p._set is not st:
                return False
        return True

    def run(self, Ys: list[np.ndarray], outs: list[np.ndarray]) -> int:
        """Project the blocks ``Ys`` ((N, n) each) into ``outs`` (C-ordered float64 (N, m) each): 0 when done, 1
        when some raw value is off the common path, 2 when the shapes disagree or an array is not one the kernel
        takes (nothing done: the numpy path decides). A block that is not C-ordered writable float64 is copied
        into one first (numba's dispatcher refuses it; nothing is checked in Python on the common path)."""
        if not self.current():
            self.pack()
        try:
            return self.kernel(*Ys, self.P, *outs)
        except TypeError:
            pass
        try:
            Ys = [np.array(Y, dtype=np.float64, order="C") for Y in Ys]
            return self.kernel(*Ys, self.P, *outs)
        except (TypeError, ValueError):  # an output buffer of another kind, or not numbers: the numpy path says so
            return 2
