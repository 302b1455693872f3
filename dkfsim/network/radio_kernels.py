"""Kernels of :class:`dkfsim.network.media.radio.RadioChannel`: what a transmission's start and
end do at every receiver (docs/radio.md, "The receivers").

The receivers' state is two arrays over the members, ``ri`` (int64 rows below) and ``rf``
(float64 rows below); each frame on the air has a slot ``s`` with its power ``p[s]`` (mW) and
distance ``d[s]`` (m) at every member, its decision draws ``u[s]``, each pair's fate
``fate[s]`` and which members sense it ``sensed[s]``; ``si[s]`` holds its sender's member index
and its start and end (ns).  One call per event does a loop over the members, so a frame heard by
hundreds of vehicles costs no Python per receiver.  A power below 0 marks a member that is not on
the road: no pair, no sensing, no interference.

On the numba path these functions are compiled; on the numpy path they run as Python.
"""

from __future__ import annotations

import math
from types import ModuleType

import numpy as np

from dkfsim.core.jit import LazyKernels

_KERNELS = ("keyed_uniform", "polevl", "p1evl", "ndtri", "fill", "error_rate", "busy_ticks", "close",
            "start", "end")
_lazy = LazyKernels(__name__, _KERNELS, inline=("keyed_uniform", "polevl", "p1evl", "error_rate", "busy_ticks"))

#: Rows of ``ri``: the slot each member is locked on (-1: none), the start of its current SINR
#: chunk, how many frames on the air it senses (its own included), since when it senses the
#: medium busy, its busy ns so far, whether it transmits, whether its last frame received was in
#: error, whether its locked frame met interference, how many frames on the air reach it.
LOCKED, CHUNK_T, SENSE_N, BUSY_FROM, BUSY_NS, TX, RXERR, INTERF, NAIR = range(9)
NRI = 9
#: Rows of ``rf``: the locked frame's power (mW) and airtime (ns), the log of its success
#: probability over the chunks so far, the power of every frame on the air (mW).
LOCK_P, LOCK_AIR, LOGPSR, TOTAL = range(4)
NRF = 4
#: Columns of ``si``: the sender's member index, start, end.
S_I, S_START, S_END = range(3)
#: A pair's fate: received, or the cause of its loss; the sender's own entry; not yet decided.
RECEIVED, SENSING, RECEIVER_BUSY, PROPAGATION, COLLISION = range(5)
SENDER, PENDING = -1, 5
#: Reception rules: a threshold (``tab_x[0]`` dB) or a table (``tab_x`` dB -> ``tab_y``).
THRESHOLD, TABLE = 0, 1


def compiled() -> ModuleType:
    """This module with its kernels compiled by numba (loaded from the disk cache after the
    first time)."""
    return _lazy.get()


_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)
_SCALE = 1.0 / 9007199254740992.0


def keyed_uniform(key: np.uint64, t: int, seq: int) -> float:
    """:func:`dkfsim.core.streams.keyed_uniform` in uint64 arithmetic (the same bits; a kernel
    module calls no other file's kernels, so this is :mod:`~dkfsim.network.port_kernels`' own)."""
    z = key + _GOLDEN * np.uint64(t)
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    z = (z ^ (z >> _S31)) + _GOLDEN * np.uint64(seq + 1)
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return (np.float64((z ^ (z >> _S31)) >> _S11) + 0.5) * _SCALE


#: Cephes ``ndtri``'s constants and its rational approximations' coefficients (:func:`ndtri`).
# sqrt(2*pi)
_SQRT2PI = 2.506628274631000502415765284811045253007
# exp(-2)
_EXPM2 = 0.13533528323661269189

# approximation for 0 <= |y - 0.5| <= 3/8
_P0 = np.array((
    -5.99633501014107895267E1,
    9.80010754185999661536E1,
    -5.66762857469070293439E1,
    1.39312609387279679503E1,
    -1.23916583867381258016E0,
), dtype=np.float64)

_Q0 = np.array((
    # 1.00000000000000000000E0 (implicit, p1evl)
    1.95448858338141759834E0,
    4.67627912898881538453E0,
    8.63602421390890590575E1,
    -2.25462687854119370527E2,
    2.00260212380060660359E2,
    -8.20372256168333339912E1,
    1.59056225126211695515E1,
    -1.18331621121330003142E0,
), dtype=np.float64)

# Approximation for interval z = sqrt(-2 log y ) between 2 and 8
# i.e., y between exp(-2) = .135 and exp(-32) = 1.27e-14.
_P1 = np.array((
    4.05544892305962419923E0,
    3.15251094599893866154E1,
    5.71628192246421288162E1,
    4.40805073893200834700E1,
    1.46849561928858024014E1,
    2.18663306850790267539E0,
    -1.40256079171354495875E-1,
    -3.50424626827848203418E-2,
    -8.57456785154685413611E-4,
), dtype=np.float64)

_Q1 = np.array((
    # 1.00000000000000000000E0 (implicit, p1evl)
    1.57799883256466749731E1,
    4.53907635128879210584E1,
    4.13172038254672030440E1,
    1.50425385692907503408E1,
    2.50464946208309415979E0,
    -1.42182922854787788574E-1,
    -3.80806407691578277194E-2,
    -9.33259480895457427372E-4,
), dtype=np.float64)

# Approximation for interval z = sqrt(-2 log y ) between 8 and 64
# i.e., y between exp(-32) = 1.27e-14 and exp(-2048) = 3.67e-890.
_P2 = np.array((
    3.23774891776946035970E0,
    6.91522889068984211695E0,
    3.93881025292474443415E0,
    1.33303460815807542389E0,
    2.01485389549179081538E-1,
    1.23716634817820021358E-2,
    3.01581553508235416007E-4,
    2.65806974686737550832E-6,
    6.23974539184983293730E-9,
), dtype=np.float64)

_Q2 = np.array((
    # 1.00000000000000000000E0 (implicit, p1evl)
    6.02427039364742014255E0,
    3.67983563856160859403E0,
    1.37702099489081330271E0,
    2.16236993594496635890E-1,
    1.34204006088543189037E-2,
    3.28014464682127739104E-4,
    2.89247864745380683936E-6,
    6.79019408009981274425E-9,
), dtype=np.float64)


def polevl(x: float, coef: np.ndarray) -> float:
    """Cephes ``polevl``: Horner's rule, ``coef[0]`` the highest degree's coefficient."""
    ans = float(coef[0])
    for i in range(1, len(coef)):
        ans = ans * x + float(coef[i])
    return ans


def p1evl(x: float, coef: np.ndarray) -> float:
    """Cephes ``p1evl``: :func:`polevl` with a leading coefficient 1 not stored."""
    ans = x + float(coef[0])
    for i in range(1, len(coef)):
        ans = ans * x + float(coef[i])
    return ans


def ndtri(y0: float) -> float:
    """The standard normal quantile of ``y0`` in (0, 1): Cephes ``ndtri`` as
    ``scipy.special.ndtri`` runs it (scipy/xsf ``include/xsf/cephes/ndtri.h``, Cephes 2.1 by
    Stephen L. Moshier), in the same operation order, so the same bits (tests/test_radio.py)."""
    if y0 == 0.0:
        return -math.inf
    if y0 == 1.0:
        return math.inf
    if y0 < 0.0 or y0 > 1.0 or y0 != y0:
        return math.nan
    code = 1
    y = y0
    if y > (1.0 - _EXPM2):
        y = 1.0 - y
        code = 0
    if y > _EXPM2:
        y = y - 0.5
        y2 = y * y
        x = y + y * (y2 * polevl(y2, _P0) / p1evl(y2, _Q0))
        return x * _SQRT2PI
    x = math.sqrt(-2.0 * math.log(y))
    x0 = x - math.log(x) / x
    z = 1.0 / x
    if x < 8.0:                             # (y > exp(-32))
        x1 = z * polevl(z, _P1) / p1evl(z, _Q1)
    else:
        x1 = z * polevl(z, _P2) / p1evl(z, _Q2)
    x = x0 - x1
    if code != 0:
        x = -x
    return x


def fill(p: np.ndarray, u: np.ndarray, slot: int, loss: np.ndarray, keys: np.ndarray, handed: int, seq0: int,
         nodes: np.ndarray, i: int, power: float, sigma: float, table: np.ndarray, z_max: float, z_steps: float,
         absent: np.ndarray) -> None:
    """Slot ``slot``'s rows for a frame member ``i`` sends, handed over at ``handed``: its power
    (mW) at every member, ``power - loss - sigma z_0 + F(z_1)`` dBm, and its decision draws
    ``u[slot]``.  Each member's three keyed draws (``keys``: shadowing, fading, decision; at
    ``(handed, seq0 + node)``) are made whether used or not; ``z_j`` is the normal quantile of
    draw ``j`` (:func:`ndtri`); ``F`` interpolates ``table``, the fading gain (dB) on the grid
    ``z = -z_max .. z_max`` in steps of ``1 / z_steps`` (no fading: fewer than two points).  The
    sender's own entry is 0; a member off the road (``absent``) gets -1 (no pair), and every
    member does when the sender itself is off the road."""
    m = len(nodes)
    nt = len(table)
    for r in range(m):
        seq = seq0 + nodes[r]
        dbm = power - loss[r]
        if sigma > 0.0:
            dbm -= sigma * ndtri(keyed_uniform(keys[0], handed, seq))
        if nt > 1:
            z = ndtri(keyed_uniform(keys[1], handed, seq))
            z = -z_max if z < -z_max else (z_max if z > z_max else z)
            x = (z + z_max) * z_steps
            j = int(x)
            if j > nt - 2:
                j = nt - 2
            lo = table[j]
            dbm += lo + (x - j) * (table[j + 1] - lo)
        p[slot, r] = 10.0 ** (dbm / 10.0)
        u[slot, r] = keyed_uniform(keys[2], handed, seq)
    p[slot, i] = 0.0
    if absent[i]:
        for r in range(m):
            p[slot, r] = -1.0
    else:
        for r in range(m):
            if absent[r]:
                p[slot, r] = -1.0


def error_rate(kind: int, tab_x: np.ndarray, tab_y: np.ndarray, sinr_db: float) -> float:
    """The packet error rate at ``sinr_db`` (``np.interp``'s rule: linear, held at the ends)."""
    if kind == THRESHOLD:
        return 0.0 if sinr_db >= tab_x[0] else 1.0
    n = len(tab_x)
    if sinr_db <= tab_x[0]:
        return tab_y[0]
    if sinr_db >= tab_x[n - 1]:
        return tab_y[n - 1]
    j = np.searchsorted(tab_x, sinr_db, side="right") - 1
    x0, x1 = tab_x[j], tab_x[j + 1]
    return tab_y[j] + (tab_y[j + 1] - tab_y[j]) * ((sinr_db - x0) / (x1 - x0))


def close(ri: np.ndarray, rf: np.ndarray, kind: int, tab_x: np.ndarray, tab_y: np.ndarray, noise: float,
          t: int) -> None:
    """Every locked member's SINR chunk up to ``t`` (its interference is about to change):
    ``logpsr += (t - chunk) / airtime * log(1 - PER(SINR))``."""
    m = ri.shape[1]
    for r in range(m):
        if ri[LOCKED, r] < 0 or ri[CHUNK_T, r] >= t:
            continue
        lp = rf[LOCK_P, r]
        other = rf[TOTAL, r] - lp
        if other < 0.0:
            other = 0.0
        per = error_rate(kind, tab_x, tab_y, 10.0 * math.log10(lp / (noise + other)))
        if per >= 1.0:
            rf[LOGPSR, r] = -math.inf
        elif per > 0.0:
            rf[LOGPSR, r] += (t - ri[CHUNK_T, r]) / rf[LOCK_AIR, r] * math.log1p(-per)
        ri[CHUNK_T, r] = t


def start(ri: np.ndarray, rf: np.ndarray, p: np.ndarray, fate: np.ndarray, sensed: np.ndarray, si: np.ndarray,
          slots: np.ndarray, ts: int, sens: float, cs: float, capture: float, went: np.ndarray) -> int:
    """The frames of ``slots`` (in their senders' order) start at ``ts``: a sender loses what it
    was receiving; a free member locks on the strongest of them at or above ``sens`` (with
    ``capture > 0`` a locked one switches to it when it is ``capture`` times stronger); every
    pair's fate so far; a member senses a frame at or above ``cs``, its own, and the one it locks
    on (its PHY is receiving: 802.11's CCA is busy); the members that begin to sense the medium
    busy, written to ``went`` (their number returned)."""
    m = ri.shape[1]
    for s in slots:                         # half duplex
        i = si[s, S_I]
        if ri[LOCKED, i] >= 0:
            fate[ri[LOCKED, i], i] = RECEIVER_BUSY
            ri[LOCKED, i] = -1
        ri[TX, i] = 1
    n = 0
    for r in range(m):
        best, bp = -1, -1.0
        for s in slots:
            if p[s, r] > bp:
                bp, best = p[s, r], s
        for s in slots:
            if si[s, S_I] == r or p[s, r] < 0.0:      # (the sender; a member off the road: no pair)
                fate[s, r] = SENDER
            elif p[s, r] < sens:
                fate[s, r] = SENSING
            else:
                fate[s, r] = RECEIVER_BUSY
        if ri[TX, r] == 0 and bp >= sens:
            lock = ri[LOCKED, r] < 0
            if not lock and capture > 0.0 and bp >= rf[LOCK_P, r] * capture:
                fate[ri[LOCKED, r], r] = COLLISION
                lock = True
            if lock:
                ri[LOCKED, r] = best
                fate[best, r] = PENDING
                rf[LOCK_P, r] = bp
                rf[LOCK_AIR, r] = si[best, S_END] - ts
                rf[LOGPSR, r] = 0.0
                ri[CHUNK_T, r] = ts
                ri[INTERF, r] = 0
        before = ri[SENSE_N, r]
        for s in slots:
            if p[s, r] > 0.0:
                rf[TOTAL, r] += p[s, r]
                ri[NAIR, r] += 1
            on = p[s, r] >= cs or si[s, S_I] == r or ri[LOCKED, r] == s     # (a PHY receiving is busy)
            sensed[s, r] = on
            if on:
                ri[SENSE_N, r] += 1
        if ri[LOCKED, r] >= 0 and ri[NAIR, r] > 1:
            ri[INTERF, r] = 1
        if before == 0 and ri[SENSE_N, r] > 0:
            ri[BUSY_FROM, r] = ts
            went[n] = r
            n += 1
    return n


def busy_ticks(ticks: np.ndarray, r: int, a: int, b: int, T_ns: int) -> None:
    """Add member ``r``'s busy interval ``[a, b)`` to ``ticks[k, r]`` (ns busy in ``[k T, (k+1) T)``;
    the last row takes what lies beyond it)."""
    last = ticks.shape[0] - 1
    k = a // T_ns
    while a < b:
        if k >= last:
            ticks[last, r] += b - a
            return
        edge = (k + 1) * T_ns
        stop = b if b < edge else edge
        ticks[k, r] += stop - a
        a = stop
        k += 1


def end(ri: np.ndarray, rf: np.ndarray, p: np.ndarray, d: np.ndarray, u: np.ndarray, fate: np.ndarray,
        sensed: np.ndarray, si: np.ndarray, slots: np.ndarray, te: int, kind: int, tab_x: np.ndarray,
        tab_y: np.ndarray, noise: float, width: float, pairs: np.ndarray, fates: np.ndarray,
        went: np.ndarray, ticks: np.ndarray, T_ns: int, window: np.ndarray, counted: np.ndarray) -> int:
    """The frames of ``slots`` end at ``te``: each member locked on one decides (received iff its
    draw is below the success probability over the chunks; lost, ``propagation`` when it had no
    interference or would have been lost without it, else ``collision``); the frames leave the
    sums; every pair of a frame started in ``[window[0], window[1])`` by a ``counted`` sender is
    counted (``fates`` by fate, ``pairs[bin, fate]`` by distance); the
    members that sense the medium idle from ``te``, written to ``went`` (their number returned),
    their busy periods added to ``ticks`` (:func:`busy_ticks`)."""
    m = ri.shape[1]
    nb = pairs.shape[0]
    n = 0
    for s in slots:
        for r in range(m):
            if ri[LOCKED, r] == s:
                lp = rf[LOCK_P, r]
                psr_noise = 1.0 - error_rate(kind, tab_x, tab_y, 10.0 * math.log10(lp / noise))
                x = u[s, r]
                if x < math.exp(rf[LOGPSR, r]):
                    fate[s, r] = RECEIVED
                    ri[RXERR, r] = 0
                else:
                    fate[s, r] = PROPAGATION if (ri[INTERF, r] == 0 or x >= psr_noise) else COLLISION
                    ri[RXERR, r] = 1
                ri[LOCKED, r] = -1
            if p[s, r] > 0.0:
                rf[TOTAL, r] -= p[s, r]
                ri[NAIR, r] -= 1
            if sensed[s, r]:
                ri[SENSE_N, r] -= 1
                if ri[SENSE_N, r] == 0:
                    ri[BUSY_NS, r] += te - ri[BUSY_FROM, r]
                    busy_ticks(ticks, r, ri[BUSY_FROM, r], te, T_ns)
                    went[n] = r
                    n += 1
            f = fate[s, r]
            if f >= 0 and window[0] <= si[s, S_START] < window[1] and counted[si[s, S_I]]:
                fates[f] += 1
                b = int(math.floor(d[s, r] / width + 1e-9))    # (a distance of whole bins: the upper)
                if b < nb:
                    pairs[b, f] += 1
        ri[TX, si[s, S_I]] = 0
    return n
