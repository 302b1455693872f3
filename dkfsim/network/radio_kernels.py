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
from collections.abc import Callable
from types import FunctionType, ModuleType
from typing import Any, cast

import numpy as np

from dkfsim.core.jit import LazyKernels

_KERNELS = ("keyed_uniform", "polevl", "p1evl", "ndtri", "fill", "error_rate", "interferes", "busy_ticks", "close",
            "start", "count_pair", "log_ended", "end", "path_loss", "distances", "first_on_air", "draw", "on_head",
            "busy", "clear", "take_due", "first_air", "soonest_end", "head", "push", "due_background", "background",
            "transmit", "finish", "next_arrival", "run", "sps_draw", "sps_select", "sps_assign", "sps_push",
            "sps_transmit", "sps_finish", "run_sps")
_lazy = LazyKernels(__name__, _KERNELS, inline=("keyed_uniform", "polevl", "p1evl", "error_rate", "interferes",
                                                "busy_ticks", "path_loss", "due_background", "count_pair", "log_ended",
                                                "distances", "first_on_air"))

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
#: Columns of ``si``: the sender's member index, start, end, its frame's number among the
#: estimators' frames (-1: background) and its hand-over instant.
S_I, S_START, S_END, S_FID, S_HANDED = range(5)
NSI = 5
#: A pair's fate: received, or the cause of its loss; the sender's own entry; not yet decided.
RECEIVED, SENSING, RECEIVER_BUSY, PROPAGATION, COLLISION = range(5)
SENDER, PENDING = -1, 5
#: Reception rules: a threshold (``tab_x[0]`` dB) or a table (``tab_x`` dB -> ``tab_y``).
THRESHOLD, TABLE = 0, 1
#: Path-loss models (:func:`path_loss`; ``plp``: their parameters, below).
PL_NONE, PL_FREE_SPACE, PL_LOG_DISTANCE, PL_TWO_RAY, PL_WINNER_B1 = range(5)
#: ``plp``: the shortest distance, the frequency, the speed of light, then the model's own (log
#: distance: reference distance, reference loss, exponent; two-ray: height, permittivity; WINNER+
#: B1: effective height).
P_MIN_D, P_FREQ, P_C, P_A, P_B, P_C2 = range(6)
#: Per-radio access rules run in the engine: a researcher's (Python, its ``on_head`` and ``sent``
#: called back), ``csma`` and ``edca`` (:mod:`~dkfsim.network.media.slotted`).
CUSTOM, CSMA, EDCA = range(3)
#: "Never": after every instant of a run (``dkfsim.network.media.channel.NEVER``).
NEVER = (1 << 62) + 1
#: :data:`NEVER` and -1 as numpy int64 (typed ``int`` for mypy), for one kernel to hand to another:
#: numba types a Python int constant as its literal value and compiles the callee once more for it
#: (and its callees); a numpy scalar is an ``int64`` like every other instant.
NEVER64 = cast(int, np.int64(NEVER))
NONE64 = cast(int, np.int64(-1))

# ------------------------------------------------------------ the engine's state (:func:`run`)
#: What :func:`run` returns: done (brought up to ``t``); estimators' frames ended or access
#: calls to make in Python (``E[E_NOWN]``, ``E[E_NHOOK]``); held frames are due (``th``); a
#: radio's background block ran out (``E[E_ARG]``); a buffer is full (``E[E_ARG]``: which).
DONE, YIELD, HELD, REFILL, GROW = range(5)
#: Buffers :data:`GROW` names: radio ``E[E_ARG2]``'s waiting room, the slots, the busy periods,
#: the dropped background, the log of ended frames.
G_QUEUE, G_SLOTS, G_PERIODS, G_DROPPED, G_LOG = range(5)
#: ``E``: the engine's scalars: the first end on the air, frames on the air, free slots, rows of
#: ``periods``, ``dropped``, ``log``, estimators' frames ended and access calls waiting for Python
#: in this call, an argument of the status, a second one, frames started so far.
E_NEXT_END, E_NAIR, E_NFREE, E_NPER, E_NDROP, E_NLOG, E_NOWN, E_NHOOK, E_ARG, E_ARG2, E_STARTED = range(11)
#: (the sidelink's) estimators' packets whose budget ran out in the waiting room in this call, and
#: background packets so dropped over the run
E_NGONE, E_EXPIRED = 11, 12
NE = 13
#: Rows of ``rq`` (per radio): its waiting room's first entry, length and bytes, the slot of its
#: frame on the air (-1: none), its background block's next packet and length (-1: no
#: background), the hand-over instant of its last frame started and how many started with it
#: (the draws' sequence).
Q_HEAD, Q_LEN, Q_BYTES, ON_AIR, B_POS, B_LEN, K_HANDED, K_SEQ = range(8)
B_POS64, B_LEN64 = cast(int, np.int64(B_POS)), cast(int, np.int64(B_LEN))    # (as :data:`NEVER64`)
NRQ = 8
#: Rows of an access rule's ``dr`` (per radio): its backoff draws' last instant and count at it.
DRAWN_AT, DRAWN = range(2)
#: Columns of a waiting room's entry (``queue[r, j]``) and of a background packet (``bg[r, j]``).
F_SIZE, F_HANDED, F_FID, F_AIR = range(4)
G_TIME, G_SIZE, G_AIR = range(3)
#: ``ip``: the access rule, slot, cw, AIFS, EIFS, tick (ns), waiting-room limits (-1: none),
#: whether ended frames are logged, the path-loss model, the reception rule, whether a
#: researcher's rule has a ``sent``.
I_RULE, I_SLOT, I_CW, I_AIFS, I_EIFS, I_T, I_MAXP, I_MAXB, I_RECORD, I_PL, I_RX, I_SENT = range(12)
NIP = 12
#: ``fp``: transmit power (dBm), shadowing sigma (dB), the fading table's grid, sensitivity,
#: carrier sense and noise (mW), the capture ratio (0: none), the distance bins' width (m), the
#: interference floor (mW; 0: none), the capture window (ns; infinity: the whole frame).
F_POWER, F_SIGMA, F_ZMAX, F_ZSTEPS, F_SENS, F_CS, F_NOISE, F_CAPTURE, F_WIDTH, F_FLOOR, F_CWIN = range(11)
NFP = 11
#: A hook for a researcher's rule (``hooks[j]``): (what, radio, instant).
H_HEAD, H_SENT = range(2)
#: Receivers per frame in a draw's sequence number (a frame's draws: ``seq = k * SEQ + node``).
SEQ = 1 << 24


def compiled() -> ModuleType:
    """This module with its kernels compiled by numba (loaded from the disk cache after the
    first time)."""
    return _lazy.get()


def quiet(kernel: Callable) -> Callable:
    """``kernel`` as the numpy path runs it: in Python, its uint64 arithmetic (the keyed draws)
    wrapping as compiled, without numpy's overflow warnings; a compiled kernel as it is."""
    if not isinstance(kernel, FunctionType):  # (compiled: a dispatcher or its entry point)
        return kernel

    def run(*args: Any) -> Any:
        with np.errstate(over="ignore"):
            return kernel(*args)
    return run


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


def interferes(p: float, floor: float) -> bool:
    """Whether a frame reaching a member with power ``p`` (mW) counts in its power on the air:
    a member on the road (``p > 0``; not its sender) at or above the interference ``floor``."""
    return p > 0.0 and p >= floor


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
          slots: np.ndarray, ts: int, sens: float, cs: float, capture: float, cwin: float, floor: float,
          went: np.ndarray) -> int:
    """The frames of ``slots`` (in their senders' order) start at ``ts``: a sender loses what it
    was receiving; a free member locks on the strongest of them at or above ``sens`` (with
    ``capture > 0`` a locked one switches to it when it is ``capture`` times stronger and starts
    at most ``cwin`` ns after the frame it is locked on); every
    pair's fate so far; a frame reaching a member at or above ``floor`` adds to its power on the
    air (:func:`interferes`); a member senses a frame at or above ``cs``, its own, and the one it
    locks on (its PHY is receiving: 802.11's CCA is busy); the members that begin to sense the
    medium busy, written to ``went`` (their number returned)."""
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
            if (not lock and capture > 0.0 and bp >= rf[LOCK_P, r] * capture
                    and ts - si[ri[LOCKED, r], S_START] <= cwin):
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
            if interferes(p[s, r], floor):
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


def count_pair(pairs: np.ndarray, fates: np.ndarray, f: int, dist: float, width: float) -> None:
    """Count a (frame, receiver) pair of fate ``f`` at ``dist`` m: in ``fates``, and in its distance
    bin of ``width`` m (a distance of whole bins in the upper; beyond the last bin, not binned)."""
    fates[f] += 1
    x = dist / width + 1e-9
    if x < pairs.shape[0]:                  # (beyond the bins, or not a number: not binned; a
        pairs[int(math.floor(x)), f] += 1   # distance past int64 once wrote outside the array)


def log_ended(log: np.ndarray, E: np.ndarray, fate: np.ndarray, si: np.ndarray, s: int, node: int, te: int) -> None:
    """Log slot ``s``'s frame, sent by ``node``, ended at ``te`` (``record``): sender, start, end,
    whether a member received it, whether it is background.  One step of both engines'
    :func:`finish` and :func:`sps_finish`."""
    m = fate.shape[1]
    lost = 0
    for q in range(m):
        if fate[s, q] != RECEIVED and fate[s, q] != SENDER:
            lost += 1
    w = E[E_NLOG]
    log[w, 0], log[w, 1], log[w, 2], log[w, 3], log[w, 4] = node, si[s, S_START], te, lost < m - 1, si[s, S_FID] < 0
    E[E_NLOG] = w + 1


def end(ri: np.ndarray, rf: np.ndarray, p: np.ndarray, d: np.ndarray, u: np.ndarray, fate: np.ndarray,
        sensed: np.ndarray, si: np.ndarray, slots: np.ndarray, te: int, kind: int, tab_x: np.ndarray,
        tab_y: np.ndarray, noise: float, floor: float, width: float, pairs: np.ndarray, fates: np.ndarray,
        went: np.ndarray, ticks: np.ndarray, T_ns: int, window: np.ndarray, counted: np.ndarray) -> int:
    """The frames of ``slots`` end at ``te``: each member locked on one decides (received iff its
    draw is below the success probability over the chunks; lost, ``propagation`` when it had no
    interference or would have been lost without it, else ``collision``); the frames leave the
    sums; every pair of a frame started in ``[window[0], window[1])`` by a ``counted`` sender is
    counted (``fates`` by fate, ``pairs[bin, fate]`` by distance); the
    members that sense the medium idle from ``te``, written to ``went`` (their number returned),
    their busy periods added to ``ticks`` (:func:`busy_ticks`)."""
    m = ri.shape[1]
    n = 0
    for s in slots:
        counts = window[0] <= si[s, S_START] < window[1] and counted[si[s, S_I]]
        for r in range(m):
            if ri[LOCKED, r] == s:
                x = u[s, r]
                if x < math.exp(rf[LOGPSR, r]):
                    fate[s, r] = RECEIVED
                    ri[RXERR, r] = 0
                else:                       # (lost without the interference too?)
                    psr_noise = 1.0 - error_rate(kind, tab_x, tab_y, 10.0 * math.log10(rf[LOCK_P, r] / noise))
                    fate[s, r] = PROPAGATION if (ri[INTERF, r] == 0 or x >= psr_noise) else COLLISION
                    ri[RXERR, r] = 1
                ri[LOCKED, r] = -1
            if interferes(p[s, r], floor):
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
            if f >= 0 and counts:
                count_pair(pairs, fates, f, d[s, r], width)
        ri[TX, si[s, S_I]] = 0
    return n


# ------------------------------------------------------------ the engine (:func:`run`)
def path_loss(kind: int, plp: np.ndarray, d: float) -> float:
    """The path loss (dB) of model ``kind`` at distance ``d`` (m; at least ``plp[P_MIN_D]``):
    :func:`dkfsim.components.radio.path_loss_db` one distance at a time (tests/test_radio.py holds
    them together)."""
    if d < plp[P_MIN_D]:
        d = plp[P_MIN_D]
    if kind == PL_NONE:
        return 0.0
    f, c = plp[P_FREQ], plp[P_C]
    if kind == PL_FREE_SPACE:
        return 20.0 * math.log10(4.0 * math.pi * d * f / c)
    if kind == PL_LOG_DISTANCE:
        d0 = plp[P_A]
        return plp[P_B] + 10.0 * plp[P_C2] * math.log10((d if d > d0 else d0) / d0)
    if kind == PL_TWO_RAY:
        h, eps = plp[P_A], plp[P_B]
        lam = c / f
        d_ref = math.sqrt(d * d + (2.0 * h) ** 2)
        sin_t, cos_t = 2.0 * h / d_ref, d / d_ref
        root = math.sqrt(eps - cos_t * cos_t)
        gamma = (sin_t - root) / (sin_t + root)
        phi = 2.0 * math.pi * (d - d_ref) / lam
        re = 1.0 / d + gamma * math.cos(phi) / d_ref
        im = gamma * math.sin(phi) / d_ref
        amp = math.hypot(re, im)
        gain = (lam / (4.0 * math.pi)) ** 2 * amp * amp
        return -10.0 * math.log10(gain if gain > 1e-300 else 1e-300)
    he = plp[P_A]                           # PL_WINNER_B1
    f_ghz = f / 1e9
    if d < 4.0 * he * he * f / c:
        return 22.7 * math.log10(d) + (27.0 + 20.0 * math.log10(f_ghz))
    return 40.0 * math.log10(d) + (7.56 - 34.6 * math.log10(he) + 2.7 * math.log10(f_ghz))


def distances(d: np.ndarray, loss: np.ndarray, s: int, r: int, k: int, px: np.ndarray, py: np.ndarray, kind: int,
              plp: np.ndarray) -> None:
    """Slot ``s``'s frame, sent by member ``r`` at tick ``k``: its distance to every member
    (``d[s]``) and the path loss over it (``loss``, what :func:`fill` takes)."""
    x0, y0 = px[k, r], py[k, r]
    for q in range(px.shape[1]):
        dist = math.hypot(px[k, q] - x0, py[k, q] - y0)
        d[s, q] = dist
        loss[q] = path_loss(kind, plp, dist)


def first_on_air(si: np.ndarray, onair: np.ndarray, n: int) -> int:
    """When the first of the ``n`` frames on the air (slots ``onair[:n]``) ends (:data:`NEVER`: none)."""
    first = NEVER64
    for j in range(n):
        e = si[onair[j], S_END]
        if e < first:
            first = e
    return first


def draw(bkey: np.ndarray, dr: np.ndarray, i: int, t: int, cw: int) -> int:
    """Radio ``i``'s backoff uniform in ``0 .. cw`` at ``t``: the keyed draw at ``(t, attempt)``,
    ``attempt`` the number of its earlier draws at ``t``
    (:meth:`dkfsim.network.media.slotted.Backoff.draw`, the same bits)."""
    if dr[DRAWN_AT, i] != t:
        dr[DRAWN_AT, i] = t
        k = 0
    else:
        k = dr[DRAWN, i]
    dr[DRAWN, i] = k + 1
    c = int(keyed_uniform(bkey[i], t, k) * (cw + 1))
    return cw if c > cw else c              # (a draw next to 1 may round up to cw + 1)


def on_head(rule: int, i: int, t: int, idle: bool, origin: np.ndarray, count: np.ndarray, due: np.ndarray,
            bkey: np.ndarray, dr: np.ndarray, cw: int, slot: int) -> None:
    """Radio ``i``'s head frame arrived at ``t`` (its medium idle or not): its count and due
    instant under ``rule`` (``edca``: immediate access after AIFS on an idle medium unless a
    backoff is pending, a backoff drawn on a busy one; ``csma``: a backoff for every head, counted
    from the first boundary at or after ``t``)."""
    if rule == EDCA:
        c = count[i]
        if c >= 0 and idle and origin[i] + c * slot < t:
            c = -1                          # the post-backoff ran out before the frame came
            count[i] = -1
        if c >= 0:
            if idle:
                due[i] = origin[i] + c * slot
        elif idle:
            due[i] = t if t > origin[i] else origin[i]
        else:
            count[i] = draw(bkey, dr, i, t, cw)
    else:
        b = draw(bkey, dr, i, t, cw)
        if idle:
            first = origin[i]
            j = 0 if t <= first else -(-(t - first) // slot)
            count[i] = j + b
            due[i] = first + (j + b) * slot
        else:
            count[i] = b


def busy(idle_at: np.ndarray, origin: np.ndarray, count: np.ndarray, due: np.ndarray, head_on: np.ndarray,
         nodes: np.ndarray, n: int, t: int, slot: int, never: int) -> int:
    """The radios ``nodes[:n]`` sense the medium busy from ``t``: each that sensed it idle keeps
    the boundaries of its count not passed before ``t`` (a head keeps at least 0 left; a
    post-backoff with nothing left and no frame to send is over: -1).  Returns how many
    changed (0: no ``due`` changed)."""
    changed = 0
    for j in range(n):
        r = nodes[j]
        if idle_at[r] < 0:
            continue
        changed += 1
        idle_at[r] = -1
        due[r] = never
        c = count[r]
        if c >= 0:
            o = origin[r]
            left = c if t <= o else c - (-((o - t) // slot))
            if head_on[r]:
                count[r] = left if left > 0 else 0
            else:
                count[r] = left if left > 0 else -1
    return changed


def clear(idle_at: np.ndarray, origin: np.ndarray, count: np.ndarray, due: np.ndarray, head_on: np.ndarray,
          nodes: np.ndarray, n: int, t: int, slot: int, aifs: int, eifs: int, error: np.ndarray) -> int:
    """The radios ``nodes[:n]`` sense the medium idle from ``t``: each counts from ``t + aifs``,
    or ``t + eifs`` when ``error[r]`` (its last frame received was in error; read and cleared
    here); a head is due at its count's boundary.  Returns how many heads were among them (0:
    no ``due`` changed)."""
    heads = 0
    for j in range(n):
        r = nodes[j]
        idle_at[r] = t
        o = t + (eifs if error[r] else aifs)
        error[r] = 0
        origin[r] = o
        if head_on[r]:
            heads += 1
            c = count[r]
            due[r] = o + c * slot if c >= 0 else o
    return heads


def take_due(due: np.ndarray, head_on: np.ndarray, count: np.ndarray, ts: int, never: int, out: np.ndarray) -> int:
    """The radios due at ``ts``, in order, written to ``out`` (their number returned): they are
    heads no more, due never, with no count."""
    n = 0
    for r in range(len(due)):
        if due[r] == ts:
            head_on[r] = False
            due[r] = never
            count[r] = -1
            out[n] = r
            n += 1
    return n


def first_air(due: np.ndarray, air: np.ndarray, ts: int) -> int:
    """The shortest airtime of the radios due at ``ts`` (-1: none)."""
    best = -1
    for r in range(len(due)):
        if due[r] == ts and (best < 0 or air[r] < best):
            best = air[r]
    return best


def soonest_end(due: np.ndarray, air: np.ndarray) -> int:
    """The first end among the radios' heads if each starts when due (:data:`NEVER`: none due)."""
    best = NEVER64
    for r in range(len(due)):
        if due[r] < NEVER and due[r] + air[r] < best:
            best = due[r] + air[r]
    return best


def head(r: int, t: int, airtime: int, E: np.ndarray, idle_at: np.ndarray, origin: np.ndarray,
         count: np.ndarray, due: np.ndarray, head_on: np.ndarray, air: np.ndarray, bkey: np.ndarray,
         dr: np.ndarray, hooks: np.ndarray, ip: np.ndarray) -> None:
    """Radio ``r``'s first waiting frame (``airtime`` ns) became its head at ``t``: the rule's
    :func:`on_head`, or a call back to a researcher's rule (``hooks``)."""
    head_on[r] = True
    air[r] = airtime
    if ip[I_RULE] == CUSTOM:
        h = E[E_NHOOK]
        hooks[h, 0], hooks[h, 1], hooks[h, 2] = H_HEAD, r, t
        E[E_NHOOK] = h + 1
    else:
        on_head(ip[I_RULE], r, t, idle_at[r] >= 0, origin, count, due, bkey, dr, ip[I_CW], ip[I_SLOT])


def push(r: int, size: int, handed: int, fid: int, airtime: int, now: int, E: np.ndarray, rq: np.ndarray,
         queue: np.ndarray, idle_at: np.ndarray, origin: np.ndarray, count: np.ndarray, due: np.ndarray,
         head_on: np.ndarray, air: np.ndarray, bkey: np.ndarray, dr: np.ndarray, hooks: np.ndarray,
         ip: np.ndarray) -> bool:
    """A frame reaches radio ``r``'s waiting room at ``now`` (False: refused, the room full; the
    caller made sure the ring has room): the frame becomes its head when the radio has nothing
    else."""
    ql = rq[Q_LEN, r]
    if ip[I_MAXP] >= 0 and ql >= ip[I_MAXP]:
        return False
    if ip[I_MAXB] >= 0 and rq[Q_BYTES, r] + size > ip[I_MAXB]:
        return False
    j = (rq[Q_HEAD, r] + ql) % queue.shape[1]
    queue[r, j, F_SIZE], queue[r, j, F_HANDED], queue[r, j, F_FID], queue[r, j, F_AIR] = size, handed, fid, airtime
    rq[Q_LEN, r] = ql + 1
    rq[Q_BYTES, r] += size
    if rq[ON_AIR, r] < 0 and ql == 0:
        head(r, now, airtime, E, idle_at, origin, count, due, head_on, air, bkey, dr, hooks, ip)
    return True


def due_background(r: int, ta: int, pos: int, bl: int, qlen: int, tick: int, bg: np.ndarray, absent: np.ndarray,
                   queue: np.ndarray, dropped: np.ndarray, E: np.ndarray) -> tuple[int, bool, bool]:
    """Radio ``r``'s background packets due at ``ta`` in its block from ``pos`` (``bl``: the
    block's end): how many, whether the radio is on the road then (``tick``: the tick length) to
    take them, and whether a buffer has no room for them (its :data:`GROW` reason set in ``E``;
    ``qlen``: the packets in its waiting room).  One step of both engines, :func:`background` and
    :func:`run_sps`."""
    n = 0
    while pos + n < bl and bg[r, pos + n, G_TIME] <= ta:
        n += 1
    k = ta // tick
    if k > absent.shape[0] - 1:
        k = absent.shape[0] - 1
    sends = not absent[k, r]
    grow = False
    if sends:
        if qlen + n > queue.shape[1]:
            E[E_ARG], E[E_ARG2] = G_QUEUE, r
            grow = True
        elif E[E_NDROP] + n > len(dropped):
            E[E_ARG] = G_DROPPED
            grow = True
    return n, sends, grow


def background(r: int, ta: int, E: np.ndarray, rq: np.ndarray, queue: np.ndarray, bg: np.ndarray,
               absent: np.ndarray, dropped: np.ndarray, idle_at: np.ndarray, origin: np.ndarray,
               count: np.ndarray, due: np.ndarray, head_on: np.ndarray, air: np.ndarray, bkey: np.ndarray,
               dr: np.ndarray, hooks: np.ndarray, ip: np.ndarray) -> int:
    """Radio ``r``'s background packets at ``ta`` reach its waiting room (a radio off the road
    takes and drops them unseen; a full room drops them, logged in ``dropped``); :data:`GROW`
    before anything changes when a buffer has no room."""
    pos = rq[B_POS, r]
    n, sends, grow = due_background(r, ta, pos, rq[B_LEN, r], rq[Q_LEN, r], ip[I_T], bg, absent, queue, dropped, E)
    if grow:
        return GROW
    if sends:
        for j in range(pos, pos + n):
            if not push(r, bg[r, j, G_SIZE], ta, NONE64, bg[r, j, G_AIR], ta, E, rq, queue, idle_at, origin, count,
                        due, head_on, air, bkey, dr, hooks, ip):
                dropped[E[E_NDROP]] = ta
                E[E_NDROP] += 1
    rq[B_POS, r] = pos + n
    return DONE


def transmit(ts: int, E: np.ndarray, rq: np.ndarray, queue: np.ndarray, idle_at: np.ndarray, origin: np.ndarray,
             count: np.ndarray, due: np.ndarray, head_on: np.ndarray, rkeys: np.ndarray, nodes: np.ndarray,
             px: np.ndarray, py: np.ndarray, absent: np.ndarray, ri: np.ndarray, rf: np.ndarray, p: np.ndarray,
             d: np.ndarray, u: np.ndarray, fate: np.ndarray, sensed: np.ndarray, si: np.ndarray, free: np.ndarray,
             onair: np.ndarray, sbuf: np.ndarray, sl: np.ndarray, went: np.ndarray, loss: np.ndarray,
             periods: np.ndarray, ip: np.ndarray, fp: np.ndarray, plp: np.ndarray, table: np.ndarray,
             tab_x: np.ndarray, tab_y: np.ndarray) -> int:
    """The heads due at ``ts`` start: each leaves its waiting room for a slot on the air, with
    its powers and draws at every member (:func:`fill`, the distances and path loss of the
    tick of ``ts``); the receivers take them (:func:`start`) and those that begin to sense the
    medium busy freeze (:func:`busy`).  :data:`GROW` before anything changes when the slots or
    the periods' log have no room."""
    m = len(nodes)
    n = 0
    for r in range(m):
        if due[r] == ts:
            n += 1
    if E[E_NFREE] < n:
        E[E_ARG] = G_SLOTS
        return GROW
    if E[E_NPER] + n > periods.shape[0]:
        E[E_ARG] = G_PERIODS
        return GROW
    n = take_due(due, head_on, count, ts, NEVER64, sbuf)
    close(ri, rf, ip[I_RX], tab_x, tab_y, fp[F_NOISE], ts)
    k = ts // ip[I_T]
    if k > px.shape[0] - 1:
        k = px.shape[0] - 1
    cap = queue.shape[1]
    for j in range(n):
        r = sbuf[j]
        h = rq[Q_HEAD, r]
        size, handed, fid, airtime = queue[r, h, F_SIZE], queue[r, h, F_HANDED], queue[r, h, F_FID], queue[r, h, F_AIR]
        rq[Q_HEAD, r] = (h + 1) % cap
        rq[Q_LEN, r] -= 1
        rq[Q_BYTES, r] -= size
        if rq[K_HANDED, r] == handed:
            rq[K_SEQ, r] += 1
        else:
            rq[K_HANDED, r] = handed
            rq[K_SEQ, r] = 0
        E[E_NFREE] -= 1
        s = free[E[E_NFREE]]
        rq[ON_AIR, r] = s
        onair[E[E_NAIR]] = s
        E[E_NAIR] += 1
        distances(d, loss, s, r, k, px, py, ip[I_PL], plp)
        fill(p, u, s, loss, rkeys[r], handed, rq[K_SEQ, r] * SEQ, nodes, r, fp[F_POWER], fp[F_SIGMA], table,
             fp[F_ZMAX], fp[F_ZSTEPS], absent[k])
        end_ = ts + airtime
        si[s, S_I], si[s, S_START], si[s, S_END], si[s, S_FID], si[s, S_HANDED] = r, ts, end_, fid, handed
        sl[j] = s
        E[E_STARTED] += 1
        w = E[E_NPER]
        periods[w, 0], periods[w, 1], periods[w, 2], periods[w, 3], periods[w, 4] = ts, end_, 1, fid < 0, 0
        E[E_NPER] = w + 1
    nw = start(ri, rf, p, fate, sensed, si, sl[:n], ts, fp[F_SENS], fp[F_CS], fp[F_CAPTURE], fp[F_CWIN], fp[F_FLOOR],
               went)
    busy(idle_at, origin, count, due, head_on, went, nw, ts, ip[I_SLOT], NEVER64)
    E[E_NEXT_END] = first_on_air(si, onair, E[E_NAIR])
    return DONE


def finish(te: int, E: np.ndarray, rq: np.ndarray, queue: np.ndarray, idle_at: np.ndarray, origin: np.ndarray,
           count: np.ndarray, due: np.ndarray, head_on: np.ndarray, air: np.ndarray, bkey: np.ndarray,
           dr: np.ndarray, nodes: np.ndarray, ri: np.ndarray, rf: np.ndarray, p: np.ndarray, d: np.ndarray, u: np.ndarray,
           fate: np.ndarray, sensed: np.ndarray, si: np.ndarray, free: np.ndarray, onair: np.ndarray,
           sl: np.ndarray, went: np.ndarray, pairs: np.ndarray, fates: np.ndarray, ticks: np.ndarray,
           window: np.ndarray, counted: np.ndarray, log: np.ndarray, own: np.ndarray, hooks: np.ndarray,
           ip: np.ndarray, fp: np.ndarray, tab_x: np.ndarray, tab_y: np.ndarray) -> int:
    """The frames on the air that end at ``te`` end, in their senders' order: the receivers
    decide (:func:`end`), those that sense the medium idle again count (:func:`clear`), each
    sender draws its post-backoff (``edca``) and its next frame becomes its head; an estimator's
    frame is listed in ``own`` (its slot: its fates stay until the next start).  :data:`GROW`
    before anything changes when the log has no room."""
    n = 0
    for j in range(E[E_NAIR]):
        s = onair[j]
        if si[s, S_END] == te:
            a = n                           # (insertion by sender: a few frames end at once)
            while a > 0 and si[sl[a - 1], S_I] > si[s, S_I]:
                sl[a] = sl[a - 1]
                a -= 1
            sl[a] = s
            n += 1
    record = ip[I_RECORD] != 0
    if record and E[E_NLOG] + n > log.shape[0]:
        E[E_ARG] = G_LOG
        return GROW
    close(ri, rf, ip[I_RX], tab_x, tab_y, fp[F_NOISE], te)
    nw = end(ri, rf, p, d, u, fate, sensed, si, sl[:n], te, ip[I_RX], tab_x, tab_y, fp[F_NOISE], fp[F_FLOOR],
             fp[F_WIDTH], pairs, fates, went, ticks, ip[I_T], window, counted)
    left = 0
    for j in range(E[E_NAIR]):
        s = onair[j]
        if si[s, S_END] != te:
            onair[left] = s
            left += 1
    E[E_NAIR] = left
    for j in range(n):
        free[E[E_NFREE]] = sl[j]
        E[E_NFREE] += 1
    if left == 0:
        for r in range(rf.shape[1]):
            rf[TOTAL, r] = 0.0              # (nothing on the air: no rounding left over)
    clear(idle_at, origin, count, due, head_on, went, nw, te, ip[I_SLOT], ip[I_AIFS], ip[I_EIFS], ri[RXERR])
    E[E_NEXT_END] = first_on_air(si, onair, left)
    cap = queue.shape[1]
    for j in range(n):
        s = sl[j]
        r = si[s, S_I]
        rq[ON_AIR, r] = -1
        if record:
            log_ended(log, E, fate, si, s, nodes[r], te)
        if si[s, S_FID] >= 0:
            own[E[E_NOWN]] = s
            E[E_NOWN] += 1
        if ip[I_RULE] == EDCA:
            count[r] = draw(bkey, dr, r, te, ip[I_CW])     # the post-backoff, counted once the medium is idle
        elif ip[I_RULE] == CUSTOM and ip[I_SENT] != 0:
            h = E[E_NHOOK]
            hooks[h, 0], hooks[h, 1], hooks[h, 2] = H_SENT, r, te
            E[E_NHOOK] = h + 1
        if rq[Q_LEN, r] > 0:
            head(r, te, queue[r, rq[Q_HEAD, r] % cap, F_AIR], E, idle_at, origin, count, due, head_on, air, bkey,
                 dr, hooks, ip)
    return DONE


def next_arrival(rows: np.ndarray, pos_row: int, len_row: int, bg: np.ndarray, E: np.ndarray) -> int:
    """The radio whose next background packet comes first (the lowest number among those at one
    instant; -1: none has background; -2: radio ``E[E_ARG]``'s block ran out, Python refills it):
    ``rows[pos_row]`` and ``rows[len_row]`` are each radio's place in its block and the block's
    length (-1: no background)."""
    ta, ra = NEVER64, -1
    for r in range(rows.shape[1]):
        bl = rows[len_row, r]
        if bl < 0:
            continue
        if rows[pos_row, r] >= bl:
            E[E_ARG] = r
            return -2
        x = bg[r, rows[pos_row, r], G_TIME]
        if x < ta:
            ta, ra = x, r
    return ra


def run(t: int, th: int, E: np.ndarray, rq: np.ndarray, queue: np.ndarray, bg: np.ndarray, idle_at: np.ndarray,
        origin: np.ndarray, count: np.ndarray, due: np.ndarray, head_on: np.ndarray, air: np.ndarray,
        bkey: np.ndarray, dr: np.ndarray, rkeys: np.ndarray, nodes: np.ndarray, px: np.ndarray, py: np.ndarray,
        absent: np.ndarray, ri: np.ndarray, rf: np.ndarray, p: np.ndarray, d: np.ndarray, u: np.ndarray,
        fate: np.ndarray, sensed: np.ndarray, si: np.ndarray, free: np.ndarray, onair: np.ndarray,
        sbuf: np.ndarray, sl: np.ndarray, went: np.ndarray, loss: np.ndarray, pairs: np.ndarray,
        fates: np.ndarray, ticks: np.ndarray, window: np.ndarray, counted: np.ndarray, periods: np.ndarray,
        dropped: np.ndarray, log: np.ndarray, own: np.ndarray, hooks: np.ndarray, ip: np.ndarray,
        fp: np.ndarray, plp: np.ndarray, table: np.ndarray, tab_x: np.ndarray, tab_y: np.ndarray) -> int:
    """Bring the radio up to ``t`` (every end and background arrival at or before ``t``, every
    start before it, in time order: at one instant the ends, then the background radio by radio,
    then the held frames (``th``: when the first is due; Python releases them), then the starts),
    or until Python must act (the status: :data:`DONE` ... :data:`GROW`).  Resumable: a call
    after Python acted goes on from the same state."""
    m = len(nodes)
    E[E_NOWN] = 0
    E[E_NHOOK] = 0
    while True:
        ra = next_arrival(rq, B_POS64, B_LEN64, bg, E)
        if ra == -2:
            return REFILL
        ta = bg[ra, rq[B_POS, ra], G_TIME] if ra >= 0 else NEVER64
        te = E[E_NEXT_END]
        ts = NEVER64
        for r in range(m):
            if due[r] < ts:
                ts = due[r]
        if te <= t and te <= ta and te <= th and te <= ts:
            st = finish(te, E, rq, queue, idle_at, origin, count, due, head_on, air, bkey, dr, nodes, ri, rf, p, d, u,
                        fate, sensed, si, free, onair, sl, went, pairs, fates, ticks, window, counted, log, own,
                        hooks, ip, fp, tab_x, tab_y)
            if st != DONE:
                return st
            if E[E_NOWN] > 0 or E[E_NHOOK] > 0:
                return YIELD
        elif ta <= t and ta <= ts and ta <= th:
            st = background(ra, ta, E, rq, queue, bg, absent, dropped, idle_at, origin, count, due, head_on, air,
                            bkey, dr, hooks, ip)
            if st != DONE:
                return st
            if E[E_NHOOK] > 0:
                return YIELD
        elif th <= t and th <= ts:
            return HELD
        elif ts < t:
            st = transmit(ts, E, rq, queue, idle_at, origin, count, due, head_on, rkeys, nodes, px, py, absent, ri,
                          rf, p, d, u, fate, sensed, si, free, onair, sbuf, sl, went, loss, periods, ip, fp, plp,
                          table, tab_x, tab_y)
            if st != DONE:
                return st
        else:
            return DONE


# ------------------------------------------------------------ the sidelink engine (:func:`run_sps`)
#: One subframe (ns): C-V2X's time unit.
SUBFRAME = 1_000_000
SUBFRAME64 = cast(int, np.int64(SUBFRAME))                # (as :data:`NEVER64`)
#: Subframes a vehicle remembers of what it sensed (the 1000 ms sensing window), and the step of
#: a candidate's images in it (100 ms).
WINDOW_SF, IMAGE_SF = 1000, 100
#: More causes of a lost pair on the sidelink: the receiver transmitted in that subframe, and a
#: collision with a transmission on a reservation (a one-shot's: ``COLLISION``).
HALF_DUPLEX, RESERVATION_COLLISION = 6, 7
NFATES = 8
#: Rows of ``vs`` (per vehicle): its reservation (held or not, an occurrence's subframe, first
#: sub-channel, sub-channels, interval in subframes, transmissions left), its head packet's
#: transmission (subframe, -1: none; first sub-channel, sub-channels, on the reservation or a
#: one-shot), its waiting room and background block (:data:`Q_HEAD` ... as ``rq``), the draws'
#: sequence of its frames, its own draws' last instant and count.
(V_ON, V_SF, V_C, V_L, V_P, V_CNT, T_SF, T_C, T_L, T_SPS, VQ_HEAD, VQ_LEN, VQ_BYTES, VB_POS, VB_LEN, VK_HANDED,
 VK_SEQ, VD_AT, VD_N) = range(19)
NVS = 19
VB_POS64, VB_LEN64 = cast(int, np.int64(VB_POS)), cast(int, np.int64(VB_LEN))    # (as :data:`NEVER64`)
#: Columns of ``sx`` (per slot): first sub-channel, sub-channels, on a reservation, the interval
#: its control message announces (0: no further reservation).
X_C, X_L, X_SPS, X_P = range(4)
#: ``sp`` (int): sub-channels, bytes a sub-channel carries, interval (subframes), counter range,
#: budget (subframes), one-shot misfits, tick (ns), waiting-room limits, reception rule, path loss,
#: whether the ended packets are logged (``record``).
(SP_S, SP_BYTES, SP_P, SP_LO, SP_HI, SP_BUDGET, SP_ONESHOT, SP_T, SP_MAXP, SP_MAXB, SP_RX, SP_PL, SP_RECORD) = range(13)
NSP = 13
#: ``sf`` (float): power (dBm), shadowing sigma, the fading grid, sensitivity and noise (mW),
#: noise share of one sub-channel, keep probability, RSRP threshold (mW) and its step (a factor), the
#: fraction of candidates kept, CBR threshold (mW per sub-channel), bin width (m), the
#: interference floor (mW; 0: none).
(SF_POWER, SF_SIGMA, SF_ZMAX, SF_ZSTEPS, SF_SENS, SF_NOISE, SF_SHARE, SF_KEEP, SF_RSRP, SF_STEP, SF_FRAC, SF_CBR,
 SF_WIDTH, SF_FLOOR) = range(14)
NSF = 14


def sps_draw(skey: np.ndarray, vs: np.ndarray, v: int, t: int) -> float:
    """Vehicle ``v``'s next keyed uniform of its scheduling at ``t`` (counters, keeps, picks)."""
    if vs[VD_AT, v] != t:
        vs[VD_AT, v] = t
        k = 0
    else:
        k = vs[VD_N, v]
    vs[VD_N, v] = k + 1
    return keyed_uniform(skey[v], t, k)


def sps_select(v: int, now: int, a: int, b: int, L: int, vs: np.ndarray, skey: np.ndarray, kn: np.ndarray,
               kr: np.ndarray, rssi: np.ndarray, txh: np.ndarray, tag: np.ndarray, sp: np.ndarray, sf: np.ndarray,
               ex: np.ndarray, metric: np.ndarray) -> int:
    """Vehicle ``v`` at subframe ``now`` picks a resource for ``L`` sub-channels in subframes
    ``a .. b`` (3GPP TS 36.213 §14.1.1.6): the candidates (subframe, first sub-channel); step 2
    excludes those whose 100 ms images in the last 1000 subframes it transmitted in, and those
    another vehicle announced it will use, heard above the RSRP threshold (raised by its step
    until the fraction ``SF_FRAC`` of them remains; the own exclusions dropped if even that
    leaves too few); step 3 keeps that fraction with the lowest mean RSSI over the images and
    picks one by a keyed draw.  Returns ``subframe * S + sub-channel``."""
    S = sp[SP_S]
    width = S - L + 1
    nc = (b - a + 1) * width
    need = int(math.ceil(sf[SF_FRAC] * nc - 1e-9))
    if need < 1:
        need = 1
    m = kr.shape[1]
    own = 1
    th = sf[SF_RSRP]
    top = -1e300
    for u in range(m):
        if u != v and kn[v, u, 0] >= now - WINDOW_SF and kn[v, u, 1] > 0 and kr[v, u] > top:
            top = kr[v, u]
    while True:
        left = 0
        for j in range(nc):
            y = a + j // width
            c = j % width
            out = False
            if own:
                for q in range(1, WINDOW_SF // IMAGE_SF + 1):
                    z = y - q * IMAGE_SF
                    if now - WINDOW_SF <= z < now and tag[z % WINDOW_SF] == z and txh[v, z % WINDOW_SF]:
                        out = True
                        break
            ex[j] = out
        for u in range(m):
            if u == v or kn[v, u, 0] < now - WINDOW_SF or kn[v, u, 1] <= 0 or kr[v, u] <= th:
                continue
            z0, p, c0, l0 = kn[v, u, 0], kn[v, u, 1], kn[v, u, 2], kn[v, u, 3]
            k = 1 if z0 + p >= a else (a - z0 + p - 1) // p
            z = z0 + k * p
            while z <= b:
                if z >= a:
                    for c in range(width):
                        if c < c0 + l0 and c0 < c + L:
                            ex[(z - a) * width + c] = True
                z += p
        for j in range(nc):
            if not ex[j]:
                left += 1
        if left >= need:
            break
        if th <= top:
            th *= sf[SF_STEP]                # (the step in dB, as a factor on the mW threshold)
        elif own:
            own = 0
            th = sf[SF_RSRP]
        else:
            break
    for j in range(nc):
        if ex[j]:
            metric[j] = math.inf
            continue
        y = a + j // width
        c = j % width
        total, n = 0.0, 0
        for q in range(1, WINDOW_SF // IMAGE_SF + 1):
            z = y - q * IMAGE_SF
            if now - WINDOW_SF <= z < now:
                n += 1
                if tag[z % WINDOW_SF] == z:
                    for cc in range(c, c + L):
                        total += rssi[v, z % WINDOW_SF, cc]
        metric[j] = total / (n * L) if n else 0.0
    order = np.argsort(metric[:nc], kind="mergesort")
    keep = need if need < left else left
    if keep < 1:
        keep = 1
    pick = order[int(sps_draw(skey, vs, v, now * SUBFRAME) * keep)]
    return (a + pick // width) * S + pick % width


def sps_assign(v: int, now: int, E: np.ndarray, vs: np.ndarray, queue: np.ndarray, gone: np.ndarray,
               skey: np.ndarray, kn: np.ndarray, kr: np.ndarray, rssi: np.ndarray, txh: np.ndarray, tag: np.ndarray,
               sp: np.ndarray, sf: np.ndarray, ex: np.ndarray, metric: np.ndarray) -> None:
    """Vehicle ``v``'s head packet became its head at subframe ``now``: the subframe and
    sub-channels it goes in, within its budget from its hand-over -- its reservation's next
    occurrence when it fits, else by ``misfit`` a new reservation or a one-shot selection.  A
    head whose budget has run out is dropped (an estimator's listed in ``gone``) and the next
    one scheduled."""
    S = sp[SP_S]
    cap = queue.shape[1]
    while vs[VQ_LEN, v] > 0:
        h = vs[VQ_HEAD, v]
        size, handed, fid = queue[v, h, F_SIZE], queue[v, h, F_HANDED], queue[v, h, F_FID]
        a, b = now + 1, handed // SUBFRAME + sp[SP_BUDGET]
        if b >= a:
            break
        vs[VQ_HEAD, v] = (h + 1) % cap
        vs[VQ_LEN, v] -= 1
        vs[VQ_BYTES, v] -= size
        if fid >= 0:
            gone[E[E_NGONE]] = fid
            E[E_NGONE] += 1
        else:
            E[E_EXPIRED] += 1
    if vs[VQ_LEN, v] == 0:
        return
    L = (size + sp[SP_BYTES] - 1) // sp[SP_BYTES]
    if vs[V_ON, v] and L <= vs[V_L, v]:
        z0, p = vs[V_SF, v], vs[V_P, v]
        occ = z0 if z0 >= a else z0 + ((a - z0 + p - 1) // p) * p
        if occ <= b:
            vs[T_SF, v], vs[T_C, v], vs[T_L, v], vs[T_SPS, v] = occ, vs[V_C, v], L, 1
            return
    pick = sps_select(v, now, a, b, L, vs, skey, kn, kr, rssi, txh, tag, sp, sf, ex, metric)
    y, c = pick // S, pick % S
    if vs[V_ON, v] and sp[SP_ONESHOT]:
        vs[T_SF, v], vs[T_C, v], vs[T_L, v], vs[T_SPS, v] = y, c, L, 0
        return
    lo, hi = sp[SP_LO], sp[SP_HI]
    vs[V_ON, v], vs[V_SF, v], vs[V_C, v], vs[V_L, v], vs[V_P, v] = 1, y, c, L, sp[SP_P]
    vs[V_CNT, v] = lo + int(sps_draw(skey, vs, v, now * SUBFRAME) * (hi - lo + 1))
    vs[T_SF, v], vs[T_C, v], vs[T_L, v], vs[T_SPS, v] = y, c, L, 1


def sps_push(v: int, size: int, handed: int, fid: int, airtime: int, now: int, E: np.ndarray, vs: np.ndarray,
             queue: np.ndarray, gone: np.ndarray, skey: np.ndarray, kn: np.ndarray, kr: np.ndarray, rssi: np.ndarray,
             txh: np.ndarray, tag: np.ndarray, sp: np.ndarray, sf: np.ndarray, ex: np.ndarray,
             metric: np.ndarray) -> bool:
    """A packet reaches vehicle ``v``'s waiting room at ``now`` (ns; False: refused -- the room
    full, or more sub-channels than the band has); alone there, it is scheduled at once."""
    ql = vs[VQ_LEN, v]
    if (size + sp[SP_BYTES] - 1) // sp[SP_BYTES] > sp[SP_S]:
        return False
    if sp[SP_MAXP] >= 0 and ql >= sp[SP_MAXP]:
        return False
    if sp[SP_MAXB] >= 0 and vs[VQ_BYTES, v] + size > sp[SP_MAXB]:
        return False
    j = (vs[VQ_HEAD, v] + ql) % queue.shape[1]
    queue[v, j, F_SIZE], queue[v, j, F_HANDED], queue[v, j, F_FID], queue[v, j, F_AIR] = size, handed, fid, airtime
    vs[VQ_LEN, v] = ql + 1
    vs[VQ_BYTES, v] += size
    if ql == 0 and vs[T_SF, v] < 0:
        sps_assign(v, now // SUBFRAME, E, vs, queue, gone, skey, kn, kr, rssi, txh, tag, sp, sf, ex, metric)
    return True


def sps_transmit(ts: int, E: np.ndarray, vs: np.ndarray, queue: np.ndarray, gone: np.ndarray, skey: np.ndarray,
                 rkeys: np.ndarray,
                 nodes: np.ndarray, px: np.ndarray, py: np.ndarray, absent: np.ndarray, p: np.ndarray,
                 d: np.ndarray, u: np.ndarray, si: np.ndarray, sx: np.ndarray, free: np.ndarray, onair: np.ndarray,
                 loss: np.ndarray, kn: np.ndarray, kr: np.ndarray, rssi: np.ndarray, txh: np.ndarray,
                 tag: np.ndarray, periods: np.ndarray, sp: np.ndarray, sf: np.ndarray, plp: np.ndarray,
                 table: np.ndarray, ex: np.ndarray, metric: np.ndarray) -> int:
    """The vehicles scheduled in the subframe starting at ``ts`` transmit their head packets:
    each a slot with its powers and draws at every member (:func:`fill`), its sub-channels and
    what its control message announces; a reservation's counter runs down (at 0: kept with
    ``SF_KEEP``, a new counter, else released); the vehicle's next packet is scheduled."""
    m = len(nodes)
    now = ts // SUBFRAME
    n = 0
    for v in range(m):
        if vs[T_SF, v] == now:
            n += 1
    if E[E_NFREE] < n:
        E[E_ARG] = G_SLOTS
        return GROW
    if E[E_NPER] + n > periods.shape[0]:
        E[E_ARG] = G_PERIODS
        return GROW
    k = ts // sp[SP_T]
    if k > px.shape[0] - 1:
        k = px.shape[0] - 1
    cap = queue.shape[1]
    for v in range(m):
        if vs[T_SF, v] != now:
            continue
        h = vs[VQ_HEAD, v]
        size, handed, fid = queue[v, h, F_SIZE], queue[v, h, F_HANDED], queue[v, h, F_FID]
        vs[VQ_HEAD, v] = (h + 1) % cap
        vs[VQ_LEN, v] -= 1
        vs[VQ_BYTES, v] -= size
        if vs[VK_HANDED, v] == handed:
            vs[VK_SEQ, v] += 1
        else:
            vs[VK_HANDED, v] = handed
            vs[VK_SEQ, v] = 0
        E[E_NFREE] -= 1
        s = free[E[E_NFREE]]
        onair[E[E_NAIR]] = s
        E[E_NAIR] += 1
        distances(d, loss, s, v, k, px, py, sp[SP_PL], plp)
        fill(p, u, s, loss, rkeys[v], handed, vs[VK_SEQ, v] * SEQ, nodes, v, sf[SF_POWER], sf[SF_SIGMA], table,
             sf[SF_ZMAX], sf[SF_ZSTEPS], absent[k])
        si[s, S_I], si[s, S_START], si[s, S_END], si[s, S_FID], si[s, S_HANDED] = v, ts, ts + SUBFRAME, fid, handed
        on_res = vs[T_SPS, v]
        sx[s, X_C], sx[s, X_L], sx[s, X_SPS], sx[s, X_P] = vs[T_C, v], vs[T_L, v], on_res, 0
        if on_res:
            vs[V_SF, v] = now
            vs[V_CNT, v] -= 1
            if vs[V_CNT, v] <= 0:
                if sps_draw(skey, vs, v, ts) < sf[SF_KEEP]:
                    lo, hi = sp[SP_LO], sp[SP_HI]
                    vs[V_CNT, v] = lo + int(sps_draw(skey, vs, v, ts) * (hi - lo + 1))
                else:
                    vs[V_ON, v] = 0
            if vs[V_ON, v]:
                sx[s, X_P] = vs[V_P, v]
        w = E[E_NPER]
        periods[w, 0], periods[w, 1], periods[w, 2], periods[w, 3], periods[w, 4] = ts, ts + SUBFRAME, 1, fid < 0, 0
        E[E_NPER] = w + 1
        E[E_STARTED] += 1
        vs[T_SF, v] = -1
    for v in range(m):                      # (the next packets, scheduled from this subframe)
        if vs[T_SF, v] < 0 and vs[VQ_LEN, v] > 0:
            sps_assign(v, now, E, vs, queue, gone, skey, kn, kr, rssi, txh, tag, sp, sf, ex, metric)
    E[E_NEXT_END] = ts + SUBFRAME
    return DONE


def sps_finish(te: int, E: np.ndarray, nodes: np.ndarray, p: np.ndarray, d: np.ndarray,
               u: np.ndarray, fate: np.ndarray, si: np.ndarray, sx: np.ndarray, free: np.ndarray,
               onair: np.ndarray, kn: np.ndarray, kr: np.ndarray, rssi: np.ndarray, txh: np.ndarray,
               tag: np.ndarray, istx: np.ndarray, pairs: np.ndarray, fates: np.ndarray, ticks: np.ndarray,
               window: np.ndarray, counted: np.ndarray, log: np.ndarray, own: np.ndarray, sp: np.ndarray,
               sf: np.ndarray, tab_x: np.ndarray, tab_y: np.ndarray) -> int:
    """The subframe ending at ``te`` is decided: at each member every packet sent in it is
    lost to ``HALF_DUPLEX`` (the member transmitted), ``SENSING`` (below sensitivity) or, from
    its SINR over its sub-channels (noise of its share of the band, interference of every other
    packet overlapping them at or above ``SF_FLOOR``), received or lost to ``PROPAGATION`` (lost without interference
    too) or a collision (``RESERVATION_COLLISION`` when an overlapping packet was on a
    reservation); a member that did not transmit hears the control message of each packet it
    detects (the sender's reservation, by the packet's power) and senses each sub-channel's
    power (RSSI, remembered 1000 subframes; busy for the CBR at ``SF_CBR``).  With ``record``
    each packet is logged as :func:`finish` logs a frame; :data:`GROW` before anything changes
    when the log has no room."""
    m = len(nodes)
    S = sp[SP_S]
    now = te // SUBFRAME - 1
    n = E[E_NAIR]
    if sp[SP_RECORD] != 0 and E[E_NLOG] + n > log.shape[0]:
        E[E_ARG] = G_LOG
        return GROW
    ring = now % WINDOW_SF
    if tag[ring] != now:
        tag[ring] = now
        for r in range(m):
            txh[r, ring] = False
            for c in range(S):
                rssi[r, ring, c] = 0.0
    for r in range(m):
        istx[r] = 0
    for j in range(n):
        v = si[onair[j], S_I]
        istx[v] = 1
        txh[v, ring] = True
    k = (te - SUBFRAME) // sp[SP_T]
    if k > ticks.shape[0] - 1:
        k = ticks.shape[0] - 1
    noise1 = sf[SF_NOISE] * sf[SF_SHARE]
    for r in range(m):
        busy = 0
        for j in range(n):
            s = onair[j]
            v = si[s, S_I]
            pj = p[s, r]
            if v == r or pj < 0.0:
                fate[s, r] = SENDER
                if v == r:
                    busy += sx[s, X_L]
                continue
            if istx[r]:
                f = HALF_DUPLEX
            elif pj < sf[SF_SENS]:
                f = SENSING
            else:
                cj, lj = sx[s, X_C], sx[s, X_L]
                interf, reserved = 0.0, False
                for q in range(n):
                    s2 = onair[q]
                    if q == j or not interferes(p[s2, r], sf[SF_FLOOR]):
                        continue
                    ov = min(cj + lj, sx[s2, X_C] + sx[s2, X_L]) - max(cj, sx[s2, X_C])
                    if ov > 0:
                        interf += p[s2, r] * ov / sx[s2, X_L]
                        if sx[s2, X_SPS]:
                            reserved = True
                noise = noise1 * lj
                per = error_rate(sp[SP_RX], tab_x, tab_y, 10.0 * math.log10(pj / (noise + interf)))
                x = u[s, r]
                if x < 1.0 - per:
                    f = RECEIVED
                elif interf == 0.0 or x >= 1.0 - error_rate(sp[SP_RX], tab_x, tab_y, 10.0 * math.log10(pj / noise)):
                    f = PROPAGATION
                else:
                    f = RESERVATION_COLLISION if reserved else COLLISION
                kn[r, v, 0], kn[r, v, 1], kn[r, v, 2], kn[r, v, 3] = now, sx[s, X_P], cj, lj
                kr[r, v] = pj
            fate[s, r] = f
            if window[0] <= si[s, S_START] < window[1] and counted[v]:
                count_pair(pairs, fates, f, d[s, r], sf[SF_WIDTH])
        if not istx[r]:
            for j in range(n):
                s = onair[j]
                pj = p[s, r]
                if pj > 0.0:
                    for c in range(sx[s, X_C], sx[s, X_C] + sx[s, X_L]):
                        rssi[r, ring, c] += pj / sx[s, X_L]
            for c in range(S):
                if rssi[r, ring, c] + noise1 >= sf[SF_CBR]:
                    busy += 1
        ticks[k, r] += busy
    for j in range(n):
        s = onair[j]
        if sp[SP_RECORD] != 0:
            log_ended(log, E, fate, si, s, nodes[si[s, S_I]], te)
        if si[s, S_FID] >= 0:
            own[E[E_NOWN]] = s
            E[E_NOWN] += 1
        free[E[E_NFREE]] = s
        E[E_NFREE] += 1
    E[E_NAIR] = 0
    E[E_NEXT_END] = NEVER
    return DONE


def run_sps(t: int, th: int, E: np.ndarray, vs: np.ndarray, queue: np.ndarray, gone: np.ndarray, bg: np.ndarray,
            skey: np.ndarray,
            rkeys: np.ndarray, nodes: np.ndarray, px: np.ndarray, py: np.ndarray, absent: np.ndarray,
            p: np.ndarray, d: np.ndarray, u: np.ndarray, fate: np.ndarray, si: np.ndarray, sx: np.ndarray,
            free: np.ndarray, onair: np.ndarray, loss: np.ndarray, kn: np.ndarray, kr: np.ndarray,
            rssi: np.ndarray, txh: np.ndarray, tag: np.ndarray, istx: np.ndarray, pairs: np.ndarray,
            fates: np.ndarray, ticks: np.ndarray, window: np.ndarray, counted: np.ndarray, periods: np.ndarray,
            dropped: np.ndarray, log: np.ndarray, own: np.ndarray, sp: np.ndarray, sf: np.ndarray, plp: np.ndarray,
            table: np.ndarray, tab_x: np.ndarray, tab_y: np.ndarray, ex: np.ndarray, metric: np.ndarray) -> int:
    """:func:`run` for the sidelink (``medium.access.kind: sps``): bring it up to ``t`` -- at one
    instant the subframe that ends, then the background vehicle by vehicle, then the held frames
    (Python's), then the subframe that starts -- or until Python must act (the same statuses)."""
    m = len(nodes)
    E[E_NOWN] = 0
    E[E_NHOOK] = 0
    E[E_NGONE] = 0
    while True:
        if E[E_NGONE] > 0:
            return YIELD
        ra = next_arrival(vs, VB_POS64, VB_LEN64, bg, E)
        if ra == -2:
            return REFILL
        ta = bg[ra, vs[VB_POS, ra], G_TIME] if ra >= 0 else NEVER64
        te = E[E_NEXT_END]
        ts = NEVER64
        for r in range(m):
            if vs[T_SF, r] >= 0 and vs[T_SF, r] * SUBFRAME < ts:
                ts = vs[T_SF, r] * SUBFRAME
        if te <= t and te <= ta and te <= th and te <= ts:
            if sps_finish(te, E, nodes, p, d, u, fate, si, sx, free, onair, kn, kr, rssi, txh, tag, istx, pairs,
                          fates, ticks, window, counted, log, own, sp, sf, tab_x, tab_y) == GROW:
                return GROW
            if E[E_NOWN] > 0:
                return YIELD
        elif ta <= t and ta <= ts and ta <= th:
            pos = vs[VB_POS, ra]
            n, sends, grow = due_background(ra, ta, pos, vs[VB_LEN, ra], vs[VQ_LEN, ra], sp[SP_T], bg, absent, queue,
                                            dropped, E)
            if grow:
                return GROW
            if sends:
                for j in range(pos, pos + n):
                    if not sps_push(ra, bg[ra, j, G_SIZE], ta, NONE64, SUBFRAME64, ta, E, vs, queue,
                                    gone, skey, kn, kr, rssi, txh, tag, sp, sf, ex, metric):
                        dropped[E[E_NDROP]] = ta
                        E[E_NDROP] += 1
            vs[VB_POS, ra] = pos + n
        elif th <= t and th <= ts:
            return HELD
        elif ts < t:
            st = sps_transmit(ts, E, vs, queue, gone, skey, rkeys, nodes, px, py, absent, p, d, u, si, sx, free, onair,
                              loss, kn, kr, rssi, txh, tag, periods, sp, sf, plp, table, ex, metric)
            if st != DONE:
                return st
        else:
            return DONE
