"""CUSUM bank on the parity vector for soft faults (small biases, slow drifts), threshold from ARL0.

For a bias ``b`` on sensor j the normalised parity is ``p ~ N(b v_j, I)``. With ``X_j = u_j^T p``
(``u_j = v_j / |v_j|``, unit variance under no fault) and ``delta_j = b |v_j|`` the log-likelihood ratio of
one sample is ``delta_j (X_j - delta_j / 2)``; Page's CUSUM accumulates it (Page 1954)::

    S_j+ = max(0, S_j+ + delta_j (X_j - delta_j / 2)),   S_j- the same with -X_j

and alarms when any statistic of the bank crosses its threshold; the sensor of that statistic is isolated.
Each threshold comes from the in-control average run length (ARL0, the mean number of samples between false
alarms) through Siegmund's approximation for Gaussian CUSUMs (Siegmund 1985, Eq. 2.57)::

    ARL(Delta) ~ (exp(-2 Delta b) + 2 Delta b - 1) / (2 Delta^2),   b = h + 1.166

in units of X (reference value k = delta / 2, Delta = mean of X - k). The bank has 2 n_active one-sided
statistics; each is designed for ``2 n_active * ARL0`` so that the bank's rate of false alarms is at most
1 / ARL0 (false alarms of the members are rare, nearly independent events). For a fault the expected delay
approaches ``ln(ARL0) / I`` with ``I = delta^2 / 2`` the Kullback-Leibler information per sample (Lorden 1971).

:func:`markov_arl` (Brook & Evans 1972) computes the run length of any CUSUM numerically; it checks
Siegmund's formula in the tests and designs the dead-band baseline (:mod:`rimu.fdi.baseline`).

Coloured noise (``noise=``, :mod:`rimu.fdi.whitening`). Bias instability and rate random walk make X_j's
mean wander; a CUSUM designed for white X then alarms far more often than 1/ARL0 over a long run. Over one
false-alarm excursion (about ``M = h / k`` samples) the slow part is nearly constant: X_j ~ N(mu, 1) with a
mean ``mu ~ N(0, sigma_mu,j^2)`` that changes slowly from excursion to excursion, ``sigma_mu,j^2 =
u_j^T C_slow(M) u_j`` (the bias-instability and random-walk part of the covariance of an M-sample mean of the
parity, over the stated horizon). The long-run rate of false alarms is then the average of the rates
(renewal: one alarm per ARL)::

    1 / ARL0_eff = E_mu[ 1 / ARL(mu - k, h) ]     (Siegmund's ARL, Gauss-Hermite quadrature over mu)

and each threshold is the h that makes this the design rate (:func:`cusum_threshold_mixture`), with M from
the white design. The white-noise design is the special case ``sigma_mu = 0``. Where sigma_mu approaches k
the threshold grows fast: the bank cannot tell a fault of the design size from the sensors' own wander.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable
from math import isfinite
from operator import mul

import numpy as np

from ..errors import NonFiniteError, ShapeError
from ..fusion.backend import resolve_backend
from .whitening import window_covariance

__all__ = ["siegmund_arl", "cusum_threshold", "cusum_threshold_mixture", "markov_arl", "CusumBank", "bias_delays"]


def siegmund_arl(drift: float, h: float) -> float:
    """Siegmund's approximation of the ARL of ``S = max(0, S + X - k)``, X ~ N(mu, 1), ``drift = mu - k``.

    Siegmund 1985 (Sequential Analysis, Eq. 2.57); h in units of X.

    >>> round(siegmund_arl(-0.5, 4.0))  # the exact value (Brook & Evans) is 336
    338
    """
    b = h + 1.166
    if abs(drift) < 1e-9:
        return b * b
    return float((np.exp(-2 * drift * b) + 2 * drift * b - 1) / (2 * drift * drift))


def cusum_threshold(arl0: float, k: float) -> float:
    """Threshold h (units of X) of a one-sided Gaussian CUSUM with reference k and in-control ARL ``arl0``.

    Inverts :func:`siegmund_arl` at ``drift = -k``.

    >>> h = cusum_threshold(1e4, 0.5)
    >>> round(siegmund_arl(-0.5, h))
    10000
    """
    if not arl0 > 1:
        raise ValueError(f"arl0 must exceed 1 sample, got {arl0}")
    if not k > 0:
        raise ValueError(f"the reference value k must be positive, got {k}")
    hi = 1.0
    while siegmund_arl(-k, hi) < arl0:
        hi *= 2.0
    from scipy.optimize import brentq  # imported where used: scipy.optimize is ~18 MB
    return float(brentq(lambda h: siegmund_arl(-k, h) - arl0, 0.0, hi))


def cusum_threshold_mixture(arl0: float, k: float, sigma_mu: float, nodes: int = 40) -> float:
    """Threshold h whose false-alarm rate averaged over a slowly varying mean ``mu ~ N(0, sigma_mu^2)`` is
    ``1 / arl0`` (module docstring); :func:`cusum_threshold` when ``sigma_mu = 0``.

    >>> h0 = cusum_threshold(1e4, 0.5)
    >>> round(cusum_threshold_mixture(1e4, 0.5, 0.0), 6) == round(h0, 6), cusum_threshold_mixture(1e4, 0.5, 0.2) > h0
    (True, True)
    """
    if not sigma_mu > 0:
        return cusum_threshold(arl0, k)
    x, w = np.polynomial.hermite_e.hermegauss(nodes)
    w = w / w.sum()
    mu = sigma_mu * x

    def excess(h: float) -> float:
        with np.errstate(over="ignore"):  # a very negative drift: ARL overflows to inf, its rate is 0
            rate = sum(wi / siegmund_arl(m - k, h) for m, wi in zip(mu, w))
        return float(np.log(rate * arl0))

    lo = cusum_threshold(arl0, k)
    hi = lo
    while excess(hi) > 0:
        hi *= 2.0
        if hi > 1e9:
            raise ValueError(f"no CUSUM threshold reaches ARL0 {arl0:g} with a wander of {sigma_mu:g} against k = {k:g}")
    from scipy.optimize import brentq  # imported where used: scipy.optimize is ~18 MB
    return float(brentq(excess, lo, hi)) if hi > lo else lo


def markov_arl(h: float, cdf: Callable[[np.ndarray], np.ndarray], states: int = 300) -> float:
    """ARL of ``S = max(0, S + X)``, alarm when ``S > h``, from zero, for increments with cumulative ``cdf``.

    Brook & Evans 1972: the interval [0, h] is cut into ``states`` cells; the transition probabilities
    between cells give the run lengths by one linear solve, ``(I - R) L = 1``.

    >>> from scipy.stats import norm
    >>> round(markov_arl(4.0, lambda x: norm.cdf(x + 0.5)), 1)  # k = 0.5, h = 4: tables give 336
    335.4
    """
    w = h / (states - 0.5)
    centres = np.arange(states) * w  # cell 0 is the atom at 0 (width w/2)
    edges_hi = centres + w / 2
    edges_lo = centres - w / 2
    hi = cdf(edges_hi[None, :] - centres[:, None])
    lo = cdf(edges_lo[None, :] - centres[:, None])
    R = hi - lo
    R[:, 0] = hi[:, 0]  # everything below w/2 (incl. the reflection at 0)
    L = np.linalg.solve(np.eye(states) - R, np.ones(states))
    return float(L[0])


#: designs kept per detector (least recently used dropped first)
_DESIGNS_KEPT = 128


def _white_only(settings):  # type: ignore[no-untyped-def]
    """The same settings at horizon 0 (white and quantisation part only)."""
    from dataclasses import replace

    return replace(settings, horizon_s=0.0)


def cached_design(detector: object, Vz: np.ndarray, dof: int):  # type: ignore[no-untyped-def]
    """``detector._design(Vz, dof)``, computed once per active set (keyed by the parity rows) and kept on the
    detector: designs depend only on the set, and the per-sample path must not redo them."""
    key = (np.asarray(Vz)[:dof].tobytes(), int(dof))
    cache = detector.__dict__.setdefault("_designs", OrderedDict())
    if key in cache:
        cache.move_to_end(key)
        return cache[key]
    cache[key] = detector._design(Vz, dof)  # type: ignore[attr-defined]
    while len(cache) > _DESIGNS_KEPT:  # bounded like the projection cache: many-sensor units see many sets
        cache.popitem(last=False)
    return cache[key]


class CusumBank:
    """Two one-sided CUSUMs per sensor on the normalised parity vector (see the module docstring).

    Parameters
    ----------
    bias : float or ndarray (n,)
        Design bias per sensor, in the units of the raw compensated output (SI). Use
        ``k * sigma`` for a bias of k sigma.
    arl0 : float
        In-control average run length of the whole bank, samples.
    noise : NoiseSettings or noise model, optional
        The sensors' noise model: each statistic is designed on its effective sigma (module docstring).
    backend : {"auto", "numpy", "numba"}, optional
        Implementation of :meth:`block` (:mod:`rimu.fusion.backend`; default ``RIMU_BACKEND``, else ``auto``:
        numba where it is installed). Both give the same bits; the compiled kernel
        (:func:`rimu.fdi._kernels.cusum_block`) costs the same however many alarms restart the bank.

    Notes
    -----
    Page's recursion ``S_k = max(0, S_{k-1} + x_k)`` is kept in its closed form (Lindley): with the running sum
    ``C_k = C_{k-1} + x_k`` and its running minimum ``M_k = min(M_{k-1}, C_k)`` (both from 0),
    ``S_k = C_k - M_k``. Both paths use it: :meth:`update` one sample at a time, :meth:`block` with
    ``np.cumsum`` and ``np.minimum.accumulate`` (sequential sums and exact minima), so the two give the same
    bits. A restart (:meth:`reset`) sets ``M = C`` (S = 0); every :data:`REBASE` samples since
    :meth:`configure` both paths move the origin, ``C <- C - M``, ``M <- 0``, so the sums stay small.

    After an alarm call :meth:`reset` to restart the statistics (the manager reconfigures when the active
    set changes); the open-loop :meth:`block` path restarts every statistic at each alarm (renewal), so its
    alarm count measures ARL0.

    Examples
    --------
    >>> from rimu.geometry import cone6
    >>> V = cone6().parity_matrix()
    >>> rng = np.random.default_rng(0)
    >>> P = rng.standard_normal((400, 3))
    >>> P[200:] += V[:, 3]                      # a 1 sigma bias on sensor 3 from sample 200
    >>> bank = CusumBank(1.0, 1e4)
    >>> ratio, _, iso = bank.block(P, V, 3)     # statistic / threshold, alarms where > 1
    >>> bank.configure(V, 3)
    >>> step = []
    >>> for p in P:
    ...     step.append(bank.update(p)[0])
    ...     if step[-1] > 1.0:
    ...         bank.reset()                    # the block path restarts after each alarm
    >>> bool(np.array_equal(step, ratio)), int(np.argmax(ratio > 1)) >= 200, int(iso[np.argmax(ratio > 1)])
    (True, True, 3)
    """

    name = "cusum"
    window = 1
    #: samples between the moves of the origin of the running sums (both paths, counted from configure); a
    #: multiple of 16
    REBASE = 4096

    def __init__(self, bias: float | np.ndarray, arl0: float = 1e5, noise: object = None,
                 backend: str | None = None) -> None:
        from .glt import as_noise_settings

        self.bias = np.asarray(bias, dtype=float)
        if np.any(self.bias <= 0):
            raise ValueError("the design bias must be positive")
        self.arl0 = float(arl0)
        self.noise = as_noise_settings(noise)
        self.backend = resolve_backend(backend)
        self._dof = 0
        self._n = 0
        self._na = 0
        self._C: list[float] = []
        self._M: list[float] = []
        self._count = 0
        self._last = -1

    # ---------------------------------------------------------------- design per active set
    def design(self, Vz: np.ndarray, dof: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Unit columns U (dof, n), delta (n,), LLR thresholds (n,) and an active mask for one set."""
        return cached_design(self, Vz, dof)

    def _design(self, Vz: np.ndarray, dof: int):  # type: ignore[no-untyped-def]
        V = Vz[:dof]
        nv = np.linalg.norm(V, axis=0)
        act = nv > 1e-12
        n = V.shape[1]
        bias = np.broadcast_to(self.bias, (n,))
        U = np.zeros_like(V)
        U[:, act] = V[:, act] / nv[act]
        delta = np.where(act, bias * nv, 0.0)
        m = 2 * int(act.sum())
        thr = np.full(n, np.inf)
        for j in np.flatnonzero(act):
            sigma_mu = self.wander(Vz, dof, U[:, j], delta[j], m * self.arl0) if self.noise is not None else 0.0
            thr[j] = delta[j] * cusum_threshold_mixture(m * self.arl0, delta[j] / 2.0, sigma_mu)
        return U, delta, thr, act

    def wander(self, Vz: np.ndarray, dof: int, u: np.ndarray, delta: float, arl: float) -> float:
        """``sigma_mu`` (units of X) of the slow mean along the unit parity direction ``u`` (module docstring)."""
        k = delta / 2.0
        M = max(cusum_threshold(arl, k) / k, 1.0)
        C = window_covariance(Vz, dof, self.noise, M) / M  # type: ignore[arg-type]  (covariance of the mean)
        C_white = window_covariance(Vz, dof, _white_only(self.noise), M) / M  # type: ignore[arg-type]
        return float(np.sqrt(max(u @ (C - C_white) @ u, 0.0)))

    def _slopes(self, Vz: np.ndarray, dof: int):  # type: ignore[no-untyped-def]
        """The active sensors' indices, LLR slopes ``W = U delta`` (dof, n_a), ``delta^2 / 2`` (n_a,) and the
        inverse thresholds of the 2 n_a statistics [S+ of each active sensor, S- of each]."""
        U, d, thr, act = self.design(Vz, dof)
        idx = np.flatnonzero(act)
        W = np.ascontiguousarray(U[:, idx] * d[idx])
        half = d[idx] * d[idx] / 2
        inv = 1.0 / thr[idx]
        return idx, W, half, np.concatenate([inv, inv])

    def configure(self, Vz: np.ndarray, dof: int) -> None:
        """Use the parity rows of a new active set; every statistic restarts at zero."""
        self._dof = int(dof)
        self._n = Vz.shape[1]
        self._na = 0
        if dof >= 1:
            idx, W, half, inv = self._slopes(Vz, dof)
            self._idx = idx.tolist()
            self._na = len(idx)
            self._cols = W.T.tolist()                      # per active sensor, its dof slopes (Python floats)
            self._half = half.tolist() * 2                 # per statistic: delta^2 / 2
            self._inv = inv.tolist()
        self._base = [0.0] * self._na
        self._part = [0.0] * self._na
        self._C = [0.0] * (2 * self._na)
        self._M = [0.0] * (2 * self._na)
        self._count = 0
        self._last = -1

    def reset(self) -> None:
        """Restart every statistic at zero in the same active set (``M = C``: S = 0)."""
        self._M = list(self._C)

    def update(self, parity: np.ndarray) -> tuple[float, float]:
        """Advance the bank by one sample; returns (largest statistic / its threshold, 1.0). A non-finite parity
        raises :class:`NonFiniteError` (as :meth:`block`) and leaves the bank as it was."""
        if self._dof < 1:
            return 0.0, float("inf")
        na = self._na
        if not na:
            return 0.0, 1.0
        p = parity.tolist()[:self._dof]
        if not all(map(isfinite, p)):  # before any state changes: the bank stays usable after the error
            raise _non_finite()
        base, part, C, M, half, inv = self._base, self._part, self._C, self._M, self._half, self._inv
        k = self._count
        if k == self.REBASE:  # move the origin before the sample (after any reset() of the last one)
            for i in range(2 * na):
                M[i] = M[i] - C[i]
            base[:] = part[:] = [0.0] * na
            k = 0
        elif k % _BLK == 0:    # a new block of the running sums: base + partial (as block() adds them)
            for j in range(na):
                base[j] = base[j] + part[j]
                part[j] = 0.0
        k += 1
        self._count = k
        kf = float(k)
        A = [0.0] * na
        for j, w in enumerate(self._cols):
            part[j] = part[j] + sum(map(mul, p, w))       # same order of operations as block()
            A[j] = part[j] + base[j]
        best, kb = 0.0, 0
        for i in range(2 * na):
            c = (A[i] if i < na else -A[i - na]) - kf * half[i]
            C[i] = c
            m = M[i]
            if c < m:
                M[i] = m = c
            r = (c - m) * inv[i]
            if r > best:
                best, kb = r, i
        self._last = self._idx[kb % na]
        return best, 1.0

    def isolate(self, parity: np.ndarray) -> tuple[int, np.ndarray]:
        """The sensor whose statistic crossed (isolable only where ``dof >= 2``), and each sensor's ratio."""
        ratios = np.zeros(self._n)
        if self._na:
            R = (np.array(self._C) - np.array(self._M)) * np.array(self._inv)
            ratios[self._idx] = np.maximum(R[: self._na], R[self._na:])
        return (self._last if self._dof >= 2 else -1), ratios

    def block(self, P: np.ndarray, Vz: np.ndarray, dof: int,
              restart: bool = True) -> tuple[np.ndarray, float, np.ndarray]:
        """Run the bank over N samples of one set, restarting after each alarm: (statistic / threshold (N,), 1.0,
        isolated sensor (N,), -1 except at alarms).

        Equal, bit for bit, to :meth:`configure` then :meth:`update` per sample with :meth:`reset` after each
        alarm (class notes); with ``restart=False``, to :meth:`update` alone (what the manager does while the
        active set stays the same: nothing restarts at an alarm). The numba backend runs
        :func:`rimu.fdi._kernels.cusum_block`: one compiled pass, whatever the alarms. The numpy backend is
        vectorised over samples, in chunks of :data:`REBASE` samples, each cut into blocks of 16 laid side by
        side, (stat, 16, blocks): the 16 steps of the running sums and minima inside the blocks are whole-array
        operations, the carries between blocks a short sequential scan; with ``restart=False`` that is one pass
        whatever the alarms; with restarts the next alarm after each one is searched in time order, over
        windows that grow from twice the last gap.

        Raises
        ------
        ShapeError
            ``P`` is not (N, >= dof).
        NonFiniteError
            ``P`` holds NaN or inf in its first ``dof`` columns (a running sum would carry it on).
        """
        P = np.asarray(P, dtype=float)
        if P.ndim != 2 or P.shape[1] < max(dof, 0):
            raise ShapeError(f"the parity block must be (N, >= dof = {dof}), got shape {P.shape}")
        N = len(P)
        if dof >= 1 and N:
            idx, W, half, inv = self._slopes(Vz, dof)
        if dof < 1 or N == 0 or len(idx) == 0:
            return np.zeros(N), 1.0, np.full(N, -1)
        if self.backend == "numba":
            from ._kernels import cusum_block

            out, iso = np.empty(N), np.empty(N, dtype=np.int64)
            if not cusum_block(P, W, half, inv, idx, dof >= 2, int(self.REBASE), _BLK, bool(restart), out, iso):
                raise _non_finite()
            return out, 1.0, iso
        out, iso = np.zeros(N), np.full(N, -1)
        with np.errstate(invalid="ignore", over="ignore"):   # checked once, on the output
            self._numpy_block(P, dof, idx, W, half, inv, restart, out, iso)
        if not np.isfinite(out).all():          # a non-finite sample spreads to every later running sum
            raise _non_finite()
        return out, 1.0, iso

    def _numpy_block(self, P: np.ndarray, dof: int, idx: np.ndarray, W: np.ndarray, half: np.ndarray,
                     inv: np.ndarray, restart: bool, out: np.ndarray, iso: np.ndarray) -> None:
        """The numpy path of :meth:`block` (fills ``out`` and ``iso``)."""
        N = len(P)
        na = len(idx)
        B, R = _BLK, int(self.REBASE)
        nbm = -(-min(N, R) // B)                                # blocks of the largest chunk
        k = np.arange(1.0, nbm * B + 1.0).reshape(nbm, B).T     # samples since the origin, (16, blocks)
        KH = half[:, None, None] * k                            # k delta^2 / 2
        inv3 = inv[:, None, None]
        M0 = np.zeros(2 * na)
        # buffers of one chunk, reused (fresh large arrays per chunk cost page faults)
        Abuf, Tbuf = np.empty((na, B, nbm)), np.empty((na, B, nbm))
        Cbuf, Mbuf = np.empty((2 * na, B, nbm)), np.empty((2 * na, B, nbm))
        ws: dict = {}
        for t in range(0, N, R):
            m = min(N - t, R)
            nb = -(-m // B)
            Pc = P[t:t + m, :dof]
            if nb * B > m:
                Pc = np.concatenate([Pc, np.zeros((nb * B - m, dof))])
            Pt = np.ascontiguousarray(Pc.reshape(nb, B, dof).transpose(2, 1, 0))   # (dof, 16, blocks)
            A, T, C, Mt = Abuf[..., :nb], Tbuf[..., :nb], Cbuf[..., :nb], Mbuf[..., :nb]
            np.multiply(W[0][:, None, None], Pt[0], out=A)
            for i in range(1, dof):
                np.multiply(W[i][:, None, None], Pt[i], out=T)
                A += T
            for i in range(1, B):                                # partial sums inside each block, in order
                np.add(A[:, i - 1], A[:, i], out=A[:, i])
            base = np.zeros((na, nb))
            np.cumsum(A[:, -1, :-1], axis=1, out=base[:, 1:])    # the sums of the earlier blocks, in order
            A += base[:, None, :]
            np.subtract(A, KH[..., :nb], out=C[:na])             # C+ = A - k delta^2 / 2
            np.negative(A, out=A)
            np.subtract(A, KH[..., :nb], out=C[na:])             # C- = -A - k delta^2 / 2
            Mt[:, 0] = C[:, 0]
            for i in range(1, B):                                # running minima inside each block
                np.minimum(Mt[:, i - 1], C[:, i], out=Mt[:, i])
            carry = np.empty((2 * na, nb))                       # the minimum before each block, from M0
            carry[:, 0] = M0
            if nb > 1:
                np.minimum.accumulate(Mt[:, -1, :-1], axis=1, out=carry[:, 1:])
                np.minimum(carry[:, 1:], M0[:, None], out=carry[:, 1:])
            np.minimum(Mt, carry[:, None, :], out=Mt)
            last = ((m - 1) % B, (m - 1) // B)
            M_end = Mt[:, last[0], last[1]].copy()
            S = np.subtract(C, Mt, out=Mt)                       # the minima are not needed past here
            S *= inv3
            best = S.max(axis=0).T.ravel()[:m]                   # time order
            hit = best > 1.0
            if not restart or not hit.any():
                out[t:t + m] = best
                Mi = M_end
                if hit.any() and dof >= 2:                       # open loop: the sensor at every alarm
                    al = np.flatnonzero(hit)
                    iso[t + al] = idx[S[:, al % B, al // B].argmax(axis=0) % na]
            else:
                a = int(hit.argmax())
                out[t:t + a + 1] = best[:a + 1]
                if dof >= 2:
                    iso[t + a] = idx[int(S[:, a % B, a // B].argmax()) % na]
                Ct = C.transpose(0, 2, 1).reshape(2 * na, nb * B)
                Mi = self._alarms(Ct, a, m, inv, idx, dof, out[t:t + m], iso[t:t + m], ws)
            M0 = Mi - C[:, last[0], last[1]] if m == R else Mi  # the origin moves (update() does the same)

    @staticmethod
    def _alarms(Ct: np.ndarray, a: int, m: int, inv: np.ndarray, idx: np.ndarray, dof: int, out: np.ndarray,
                iso: np.ndarray, ws: dict) -> np.ndarray:
        """After the alarm at ``a`` of a chunk, the rest of it in time order (``Ct`` (stat, >= m)); fills
        ``out`` and ``iso``, returns the running minima at the chunk's end.

        A restart at ``a`` sets ``M = C_a``, so the running minimum of a window that starts at the alarm
        sample is the restarted one: one ``np.minimum.accumulate`` per alarm. Where alarms come within
        :data:`_DENSE` samples of each other, :func:`_dense_alarms` finds many per call."""
        na = len(idx)
        inv = inv[:, None]
        w = max(32, 2 * (a + 1))
        Mi: np.ndarray | None = None                             # None: the window starts at the alarm sample
        s = a
        gap = a + 1
        while True:
            if Mi is None and gap <= _DENSE // 2 and s < m - 1:
                s, Mi, gap = _dense_alarms(Ct, s, m, inv, idx, dof, out, iso, ws)
                if s >= m:
                    return Mi                                    # type: ignore[return-value]
                if Mi is None:
                    continue
            if Mi is None:                                       # window [s, e): s is the alarm, M starts at C_s
                e = min(m, s + 1 + w)
                Mw = np.minimum.accumulate(Ct[:, s:e], axis=1)[:, 1:]
                s += 1
            else:
                e = min(m, s + w)
                Mw = np.minimum.accumulate(Ct[:, s:e], axis=1)
                np.minimum(Mw, Mi[:, None], out=Mw)
            if e <= s:
                return Ct[:, s - 1].copy() if Mi is None else Mi
            Sw = Ct[:, s:e] - Mw
            Sw *= inv
            best = Sw.max(axis=0)
            k = int((best > 1.0).argmax())
            if best[k] > 1.0:
                out[s:s + k + 1] = best[:k + 1]
                if dof >= 2:
                    iso[s + k] = idx[int(Sw[:, k].argmax()) % na]
                s += k
                Mi = None
                gap = k + 1
                w = max(32, 2 * gap)
            else:
                out[s:e] = best
                Mi = Mw[:, -1].copy()
                s = e
                w = 2 * w
            if s >= m:
                return Mi if Mi is not None else Ct[:, m - 1].copy()


#: alarms at most this many samples apart are found together (:func:`_dense_alarms`)
_DENSE = 4


def _dense_alarms(Ct: np.ndarray, a0: int, m: int, inv: np.ndarray, idx: np.ndarray, dof: int, out: np.ndarray,
                  iso: np.ndarray, ws: dict) -> tuple[int, np.ndarray | None, int]:
    """Alarms close together, from the alarm (restart) at ``a0``, over a window of up to 512 samples.

    With a restart at a, the statistic j at k is ``(C_jk - min_{a<=i<=k} C_ji) inv_j``, the largest of
    ``(C_jk - C_ji) inv_j`` over i (the rounding is monotone: the same bits). For the gaps d = k - a up to
    L = :data:`_DENSE` the whole window gets ``V_d[j, k] = max_{i >= k-d} (C_jk - C_ji) inv_j`` at once; the
    chain of alarms (a -> the first k in (a, a+L] with ``max_j V_{k-a}[j, k] > 1``) is then a walk over
    Python floats. Returns (position, M, last gap): the next alarm sample with M None when the chain ran to
    the window's end; else the sample after L alarm-free samples with their running minimum M (or the
    chunk's end)."""
    L = _DENSE
    na = len(idx)
    e0 = min(m, a0 + 512)
    Cw = Ct[:, a0:e0]
    n = Cw.shape[1]
    if "V" not in ws:                                           # one buffer per block() call
        ws["V"] = np.zeros((L + 1, Cw.shape[0], 512))
    V = ws["V"][..., :n]
    for d in range(1, L + 1):
        if d < n:
            V[d, :, :d] = 0.0                                   # never read (k >= d); kept finite
            Dd = np.subtract(Cw[:, d:], Cw[:, :-d], out=V[d, :, d:])
            Dd *= inv
            np.maximum(Dd, V[d - 1, :, d:], out=Dd)
    Q = V.max(axis=1)                                           # (L + 1, n): the bank's ratio for each gap
    hit = Q > 1.0
    nxt = np.full(n, -1)                                        # the next alarm after a restart at each sample
    pos = np.arange(n)
    for d in range(min(L, n - 1), 0, -1):                       # the smallest gap wins
        h = hit[d, d:]
        nxt[:n - d][h] = pos[d:][h]
    nl = nxt.tolist()
    restarts = [0]
    a = 0
    while nl[a] >= 0:                                           # the chain of alarms: pointer chasing
        a = nl[a]
        restarts.append(a)
    quiet_end = a + L if a + L < n else -1                      # L samples after a without an alarm, or the end
    end = quiet_end if quiet_end >= 0 else n - 1                # the last sample covered here
    ks = np.arange(1, end + 1)
    R = np.asarray(restarts)
    d_k = ks - R[np.searchsorted(R, ks - 1, side="right") - 1]
    out[a0 + 1:a0 + end + 1] = Q[d_k, ks]
    if dof >= 2 and len(R) > 1:
        al = R[1:]
        d_al = np.diff(R)
        iso[a0 + al] = idx[np.argmax(V[d_al, :, al], axis=1) % na]
    if quiet_end >= 0:
        s = a0 + quiet_end + 1
        M = Cw[:, a:quiet_end + 1].min(axis=1)
        return s, M, L + 1
    last = a0 + restarts[-1]
    if e0 >= m:                                                 # the chunk ends inside the chain
        return m, Ct[:, last:m].min(axis=1), 1
    return last, None, 1


def _non_finite() -> NonFiniteError:
    return NonFiniteError("the parity block holds a non-finite value (NaN or inf); the CUSUM's running sums would "
                          "carry it to every later sample: leave invalid samples out of the block (or set their "
                          "parity to 0, as the campaign does) before calling block() or update()")


#: samples per block of the running sums (both paths: the sum is the earlier blocks' sum plus a partial sum)
_BLK = 16


def bias_delays(bank: CusumBank, V: np.ndarray, dof: int, trials: int, rng: np.random.Generator,
                length: int = 400, onset: int = 100, size: float = 1.0) -> np.ndarray:
    """Detection delays (samples, 1 = the onset sample) of ``bank`` for a bias of ``size`` sigma on each sensor
    in turn (trial r: sensor r mod n), on unit-noise parity of ``length`` samples from ``onset``; NaN where no
    alarm came. The Monte Carlo behind the delay figures that are held against Lorden's ln(ARL0)/I."""
    V = np.asarray(V, float)
    n = V.shape[1]
    out = np.full(trials, np.nan)
    for r in range(trials):
        P = rng.standard_normal((length, dof))
        P[onset:] += size * V[:dof, r % n]
        s, _, _ = bank.block(P, V, dof)
        hits = np.flatnonzero(s[onset:] > 1.0)
        if hits.size:
            out[r] = hits[0] + 1
    return out
