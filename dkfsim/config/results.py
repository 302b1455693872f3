"""The schema of what dkfsim reads back: result folders and sweep databases, validated as scenarios are.

A result may come from anyone (docs/security.md), so every reader validates what it
read with these pydantic models before using it, and a wrong type, a missing key, a
name of megabytes or rows that do not fit together is one message in the scenario
style (:func:`dkfsim.config.messages.convert`): ``<file>: <dotted.key>: <what is wrong>``.

* :class:`RunSummary` -- ``summary.json`` of ``dkfsim run``, its ``rows`` (:class:`Row`);
* :class:`MonteCarloSummary` -- ``summary.json`` of ``dkfsim montecarlo``;
* :class:`Row` -- one tidy row (``rows.csv``, ``runs.csv``, a sweep's ``results`` table);
* :class:`SweepDefinition` -- a sweep database's ``meta.definition``;
* :func:`read_rows` -- a ``rows.csv`` / ``runs.csv`` as validated tidy rows;
* :func:`read_curves` -- a Monte Carlo ``curves.npz``, every header checked before its data.

Models accept keys they do not know (older and newer folders carry other facts), and check
the type of every key dkfsim writes (a count is an integer >= 0, a list a list, wherever it
sits: ``traffic.<estimate>.per_link.3.sent``) and the consistency of those the readers use.
Names (estimates, components, scenarios) are at most :data:`NAME_LIMIT` characters, the
limit the scenario schema puts on them when a run is written
(:mod:`dkfsim.core.params`): they become table cells and figure labels.
"""

from __future__ import annotations

import csv
import functools
import io
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError, create_model, model_validator

from dkfsim.config.messages import convert
from dkfsim.core.errors import DkfsimError, ScenarioError
from dkfsim.core.files import clip, open_regular, read_json
from dkfsim.core.npzfile import NpzFile
from dkfsim.core.params import NAME_LIMIT, TEXT_LIMIT, Name, custom_error

#: Estimate names of folders written before the one vocabulary (``algorithms`` in Monte Carlo
#: output), mapped to today's names.
OLD_NAMES = {"anti_delay_dkf": "fused", "anti_delay_dkf_local": "local", "local": "local_only"}

Text = Annotated[str, Field(strict=True, max_length=TEXT_LIMIT)]     # (may be empty: a rule's note)
Number = Annotated[float, Field(strict=True)]        # an int is read as a float; bool and text are not
MaybeNumber = Number | None
Count = Annotated[int, Field(strict=True, ge=0)]
Positive = Annotated[int, Field(strict=True, ge=1)]
Pair = tuple[MaybeNumber, MaybeNumber]


class Model(BaseModel):
    """A record read back: other keys are allowed (and kept), the known ones are checked."""

    model_config = ConfigDict(extra="allow", frozen=True)


class Measures(Model):
    """The metrics a tidy row and a Monte Carlo estimate share (None: not applicable)."""

    anees: MaybeNumber = None
    disagreement: MaybeNumber = None
    messages_per_tick: MaybeNumber = None
    bytes_per_tick: MaybeNumber = None
    lost: MaybeNumber = None
    late: MaybeNumber = None


class Row(Measures):
    """One tidy row: one estimate and state component of one run (docs/design.md §8)."""

    run: Count
    seed: Count
    estimate: Name
    component: Name
    mse: MaybeNumber = None


_NUMBERS = TypeAdapter(list[MaybeNumber])


class Metrics(Model):
    """summary.json ``metrics``: the burn-in, then each estimate's MSE per component."""

    burn_in: Count | None = None

    @model_validator(mode="after")
    def _estimates_hold_numbers(self):
        for name, values in (self.model_extra or {}).items():
            try:
                _NUMBERS.validate_python(values)
            except ValidationError as exc:
                err = exc.errors()[0]
                raise custom_error(err["msg"], ".".join([name, *(str(p) for p in err["loc"])])) from None
        return self


NonNeg = Annotated[float, Field(strict=True, ge=0)]
#: A node of a link's row: -1 is the centre of ``centralized_delayed`` (its sensors' links).
Node = Annotated[int, Field(strict=True, ge=-1)]


class PacketCounts(Model):
    """The packet counts a link's row and an estimator's block both have (the terms of
    ``sent + copies = delivered + lost + queue_dropped + crash_dropped + in_flight``)."""

    sent: Count | None = None
    delivered: Count | None = None
    lost: Count | None = None
    copies: Count | None = None
    crash_dropped: Count | None = None
    outage_lost: Count | None = None
    bytes: Count | None = None
    queue_dropped: Count | None = None
    collision_lost: Count | None = None
    range_lost: Count | None = None
    in_flight: Count | None = None


class _Linked(Model):
    link: tuple[Node, Node]


class LinkCounts(PacketCounts, _Linked):
    """One link's counts (summary.json ``per_link`` and ``traffic.<estimate>.per_link`` rows);
    a rate-limited link's row has its utilisation and queueing delays too.  (``link`` comes
    first: pydantic orders the fields of the last base first.)"""

    late_packets: Count | None = None
    background_sent: Count | None = None
    background_dropped: Count | None = None
    utilisation: NonNeg | None = None
    queue_length_mean: NonNeg | None = None
    queueing_delay_mean: NonNeg | None = None
    queueing_delay_p95: NonNeg | None = None

    @model_validator(mode="after")
    def _rated_rows_whole(self):
        if self.utilisation is not None:
            for key in ("queueing_delay_mean", "queueing_delay_p95"):
                if getattr(self, key) is None:
                    raise custom_error("a rate-limited link's row (it has utilisation) needs it", key)
        return self


def components_of(rows) -> list[str]:
    """The state components of tidy rows, in their order of appearance."""
    out: list[str] = []
    for r in rows:
        c = r.component if isinstance(r, Row) else r["component"]
        if c not in out:
            out.append(c)
    return out


class MobilityRecord(Model):
    """summary.json's ``mobility`` (a run with ``mobility:``): ``link_uptime`` rows ``[u, v,
    fraction]``, the fraction of the run's ticks at which the pair's link was up (decision 187)."""

    link_uptime: list[tuple[Count, Count, Annotated[float, Field(ge=0, le=1)]]]


Fraction = Annotated[float, Field(strict=True, ge=0, le=1)]
#: The longest list of a radio block: the distance bins (``DistanceBins`` allows 10,000) and the
#: members of a channel.
RADIO_LIST = 100_000


#: The causes of a lost (frame, receiver) pair a radio block may hold, in the order tables and
#: figures show them: 802.11p's (``receiver_busy``) and the C-V2X sidelink's (``half_duplex``,
#: ``reservation_collision``) among them (docs/radio.md).
RADIO_CAUSES = ("sensing", "half_duplex", "receiver_busy", "propagation", "reservation_collision", "collision")


class PdrByDistance(Model):
    """A spatial radio's ``pdr_by_distance`` (docs/radio.md): the bins' edges (m), the packet
    delivery ratio per bin (null: no pair fell in it), the (frame, receiver) pairs per bin and
    each cause of a loss per bin."""

    bins_m: Annotated[list[Annotated[float, Field(strict=True, ge=0)]], Field(min_length=2, max_length=RADIO_LIST)]
    pdr: Annotated[list[Fraction | None], Field(max_length=RADIO_LIST)]
    frames: Annotated[list[Count], Field(max_length=RADIO_LIST)]
    sensing: Annotated[list[Count], Field(max_length=RADIO_LIST)] | None = None
    half_duplex: Annotated[list[Count], Field(max_length=RADIO_LIST)] | None = None
    receiver_busy: Annotated[list[Count], Field(max_length=RADIO_LIST)] | None = None
    propagation: Annotated[list[Count], Field(max_length=RADIO_LIST)] | None = None
    reservation_collision: Annotated[list[Count], Field(max_length=RADIO_LIST)] | None = None
    collision: Annotated[list[Count], Field(max_length=RADIO_LIST)] | None = None

    @model_validator(mode="after")
    def _shapes(self) -> PdrByDistance:
        bins = len(self.bins_m) - 1
        for key in ("pdr", "frames", *RADIO_CAUSES):
            value = getattr(self, key)
            if value is not None and len(value) != bins:
                raise custom_error(f"has {len(value)} entries for {bins} distance bins (bins_m has {bins + 1} edges)",
                                   key)
        if any(b <= a for a, b in zip(self.bins_m, self.bins_m[1:])):
            raise custom_error("the bins' edges must increase", "bins_m")
        return self


class Losses(Model):
    """A spatial radio's lost (frame, receiver) pairs by cause (802.11p's ``receiver_busy``, the
    sidelink's ``half_duplex`` and ``reservation_collision``: :data:`RADIO_CAUSES`)."""

    sensing: Count
    half_duplex: Count | None = None
    receiver_busy: Count | None = None
    propagation: Count
    reservation_collision: Count | None = None
    collision: Count


class ChannelRecord(Model):
    """An estimator's ``channel`` block (a run with ``medium:``, docs/channel.md): the shared
    channel as its copy saw it; what ``dkfsim report`` shows of it.  A spatial radio
    (``medium.radio``, docs/radio.md) adds ``pdr_by_distance``, ``cbr`` (per member),
    ``cbr_mean``, ``losses``, ``pairs`` and ``pairs_received``."""

    utilisation: Annotated[float, Field(strict=True, ge=0)]
    frames: Count
    frames_collided: Count
    frames_dropped: Count
    background_sent: Count
    background_collided: Count
    background_dropped: Count = 0
    access_delay_mean: Annotated[float, Field(strict=True, ge=0)]
    frames_on_air: Count | None = None
    cbr: Annotated[list[Fraction], Field(max_length=RADIO_LIST)] | None = None
    cbr_mean: Fraction | None = None
    pdr_by_distance: PdrByDistance | None = None
    losses: Losses | None = None
    pairs: Count | None = None
    pairs_received: Count | None = None


class Counts(PacketCounts):
    """An estimator's packet counts: summary.json ``packets`` (the DKF's) and each
    ``traffic.<estimate>`` block."""

    late: Count | None = None
    late_per_node: list[Count] | None = None
    late_unit: Text | None = None
    duplicates: Count | None = None
    stale: Count | None = None
    per_link: list[LinkCounts] | None = None
    channel: ChannelRecord | None = None


def _check_block(model, block: Any, key: str, what: str = "") -> None:
    """``block`` (None: none) checked with ``model`` and left as it is (no defaults added), its
    first problem raised under ``key`` (a dotted path in summary.json)."""
    if block is None:
        return
    try:
        model.model_validate(block)
    except ValidationError as exc:
        err = exc.errors()[0]
        ctx = err.get("ctx") or {}
        where = ".".join([key, *(str(p) for p in err["loc"]), *([str(ctx["key"])] if ctx.get("key") else [])])
        msg = ctx.get("reason") or err["msg"]
        raise custom_error(msg + (f" ({what})" if what else ""), where) from None


def _check_channel(block: Any, key: str) -> None:
    _check_block(ChannelRecord, block, key, "the channel block of a run with medium:")


class RunSummary(Model):
    """``summary.json`` of ``dkfsim run``: what ``load_run``, ``plot`` and ``report`` use of it,
    and the type of every other key a run writes."""

    scenario: Text
    scenario_hash: Text | None = None
    source: Text | None = None
    seed: Count
    steps: Positive
    protocol: Text | None = None
    weights: Text | None = None
    fusion: Text | None = None
    estimates: Annotated[list[Name], Field(min_length=1)]
    metrics: Metrics = Field(default_factory=Metrics)
    rows: list[Row]
    packets: dict[str, Any]
    per_link: list[dict[str, Any]] = []
    traffic: dict[Name, dict[str, Any] | None] = {}
    facts: dict[Name, dict[str, Any] | None] = {}        # (an estimator's own facts: any JSON)
    diverged: list[Text] = []
    scenario_config: dict[str, Any]
    versions: dict[Name, Text] = {}
    buffer_length: Count | None = None
    d_t: Count | None = None
    d_g: Count | None = None
    n_links: Count | None = None
    wall_time_s: NonNeg | None = None
    save: Text | None = None
    kernels: Text | None = None
    node_rows: Count | None = None
    exchange: Text | None = None
    backend: dict[Name, Text] = {}
    mobility: MobilityRecord | None = None

    @model_validator(mode="after")
    def _rows_cover_the_estimates(self):
        have = {(r.estimate, r.component) for r in self.rows}
        comps = components_of(self.rows) or ["?"]
        for e in self.estimates:
            for c in comps:
                if (e, c) not in have:
                    raise custom_error(f"no row for estimate {clip(e)}, component {clip(c)} (the "
                                       "rows do not match the estimates)", "rows")
        return self

    @model_validator(mode="after")
    def _blocks_hold_counts(self):
        _check_block(Counts, self.packets, "packets")
        for i, row in enumerate(self.per_link):
            _check_block(LinkCounts, row, f"per_link.{i}")
        for name, t in self.traffic.items():
            _check_block(Counts, t, f"traffic.{name}")
        return self


class Paired(Model):
    """An estimate's ``paired`` block: its MSE against the reference estimate, run by run."""

    reference: Name
    runs: Count = 0
    mse_diff: dict[Name, MaybeNumber] = {}
    mse_diff_ci95: dict[Name, Pair] = {}
    mse_ratio: dict[Name, MaybeNumber] = {}
    mse_ratio_ci95: dict[Name, Pair] = {}


class EstimateStats(Measures):
    """One estimate's pooled numbers in a Monte Carlo ``summary.json``."""

    mse: dict[Name, MaybeNumber]
    mse_ci95: dict[Name, Pair]
    anees_ci95: Pair | None = None
    anees_consistent: Annotated[bool, Field(strict=True)] | None = None
    anees_band95: Pair | None = None
    anees_fraction_in_band: MaybeNumber = None
    paired: Paired | None = None


class MonteCarloSummary(Model):
    """``summary.json`` of ``dkfsim montecarlo``: what ``plot`` and ``report`` use of it."""

    scenario: Text
    source: Text | None = None
    runs: Positive
    base_seed: Count | None = None
    steps: Positive | None = None
    components: Annotated[list[Name], Field(min_length=1)] | None = None
    estimates: Annotated[dict[Name, EstimateStats], Field(min_length=1)]
    burn_in: Count | None = None
    relative_to: Name | None = None
    scenario_config: dict[str, Any] = {}
    versions: dict[Name, Text] = {}
    seed_rule: Text = ""
    buffer_length: Count | None = None
    d_t: Count | None = None
    d_g: Count | None = None
    scenario_hash: Text | None = None
    protocol: Text | None = None
    fusion: Text | None = None
    jobs: Count | None = None
    wall_time_s: NonNeg | None = None
    notes: dict[Name, Text] = {}

    @model_validator(mode="before")
    @classmethod
    def _older_spellings(cls, data: Any) -> Any:
        """Folders of earlier versions: ``algorithms`` (old names) for ``estimates``, a
        ``scenario`` mapping with a ``name``."""
        if not isinstance(data, dict):
            return data
        data = dict(data)
        if "estimates" not in data and isinstance(data.get("algorithms"), dict):
            data["estimates"] = {OLD_NAMES.get(k, k): v for k, v in data.pop("algorithms").items()}
        if "runs" not in data and "n_runs" in data:
            data["runs"] = data["n_runs"]
        if isinstance(data.get("scenario"), dict) and isinstance(data["scenario"].get("name"), str):
            data["scenario"] = data["scenario"]["name"]
        return data

    @model_validator(mode="after")
    def _every_component(self):
        components = self.components or list(next(iter(self.estimates.values())).mse)
        for name, e in self.estimates.items():
            for field in ("mse", "mse_ci95"):
                missing = [c for c in components if c not in getattr(e, field)]
                if missing:
                    raise custom_error(f"no value for component {clip(missing[0])}",
                                       f"estimates.{name}.{field}")
        return self


class SweepDefinition(Model):
    """A sweep database's ``meta.definition`` (what the readers use of it)."""

    grid: list[tuple[Annotated[str, Field(strict=True, min_length=1, max_length=TEXT_LIMIT)], list[Any]]]
    runs: Positive
    set: list[Text] = []
    scenario_file: Text | None = None
    burn_in: Count | None = None


@functools.lru_cache(maxsize=16)
def sweep_rows(metrics: tuple[str, ...]) -> Any:
    """The type of the rows (mappings) of a sweep's ``results`` table with these metric columns."""
    fields: dict[str, Any] = {"param_hash": (Name, ...), "run": (Count, ...), "seed": (Count, ...),
                              "estimate": (Name, ...), "component": (Name, ...),
                              **{m: (MaybeNumber, None) for m in metrics}}
    row = create_model("SweepRow", __base__=Model, **fields)
    return list[row]  # type: ignore[valid-type]


class SweepParams(Model):
    """A row of a sweep database's ``params`` table (its JSON columns parsed)."""

    idx: Annotated[int, Field(strict=True)]
    param_hash: Name
    base_seed: Count
    values: dict[str, Any]
    scenario: dict[str, Any]


def validate(model, data: Any, label: str):
    """``data`` validated with ``model`` (a pydantic class or a type); :class:`ScenarioError`
    ``"<label>: <dotted.key>: <reason>"`` otherwise."""
    try:
        if isinstance(model, type) and issubclass(model, BaseModel):
            return model.model_validate(data)
        return _adapter(model).validate_python(data)
    except ValidationError as exc:
        raise convert(exc, data, label, {}, max_items=3) from None
    except (RecursionError, MemoryError):
        raise ScenarioError("too deeply nested or too large to check", source=label) from None


@functools.cache
def _adapter(tp) -> TypeAdapter:
    return TypeAdapter(tp)


# =========================================================================== reading files
#: Largest ``runs.csv`` read back (bytes): a 10 000-run Monte Carlo of a few estimates is ~20 MB.
MAX_CSV_BYTES = 256 << 20


def read_record(path, model, what: str) -> dict:
    """A JSON file of a result (``summary.json``) validated with ``model``, as plain data
    (the model's keys normalised, other keys kept).  Raises :class:`DkfsimError`."""
    data = read_json(path, what=what)
    if not isinstance(data, dict):
        raise ScenarioError(f"must be a JSON object (a mapping of keys), got {type(data).__name__}",
                            source=str(path))
    return validate(model, data, str(path)).model_dump()


def _csv_lines(path, what: str, first: list[str], writer: str):
    """The header, then each non-empty line as ``(number, cells)``, of a CSV file dkfsim
    wrote, read as a stream; the header must start with ``first``.  Every reading problem
    (size, encoding, CSV syntax) becomes a :class:`DkfsimError` naming the file."""
    label = str(path)
    raw = open_regular(path, limit=MAX_CSV_BYTES, what=what)
    try:
        with io.TextIOWrapper(raw, newline="", encoding="utf-8") as fh:
            reader = csv.reader(fh)
            head = next(reader, None)
            if not head or head[:len(first)] != first:
                raise DkfsimError(f"{label}: not a {what} written by {writer} (its header is "
                                  f"{clip(head)}, expected {', '.join(first)}, ...)")
            yield head
            for line, cells in enumerate(reader, 2):
                if cells:
                    yield line, cells
    except UnicodeDecodeError as exc:
        raise DkfsimError(f"{label}: not a UTF-8 text file ({exc.reason} at byte {exc.start})") from None
    except (csv.Error, OSError) as exc:
        raise DkfsimError(f"{label}: cannot read as CSV ({clip(str(exc), 120)})") from None


def read_run_seeds(path) -> dict[int, int]:
    """``{run: seed}`` of a Monte Carlo ``runs.csv``, read as a stream (the file is only
    needed for its first two columns).  Raises :class:`DkfsimError`."""
    label = str(path)
    lines = _csv_lines(path, "runs.csv", ["run", "seed"], "dkfsim montecarlo")
    next(lines)
    seeds: dict[int, int] = {}
    for line, row in lines:
        try:
            run, seed = int(row[0]), int(row[1])
            if run < 0 or seed < 0:
                raise ValueError
        except (ValueError, IndexError):
            raise DkfsimError(f"{label}: line {line}: run and seed must be integers >= 0, got "
                              f"{clip(row[:2])}") from None
        if seeds.setdefault(run, seed) != seed:
            raise DkfsimError(f"{label}: line {line}: run {run} has two seeds")
    return seeds


def read_rows(path, what: str = "runs.csv") -> list[dict]:
    """The tidy rows of a ``runs.csv`` (or ``rows.csv``): ``run, seed, estimate, component``
    then metric columns, every row checked with :class:`Row` (numbers as numbers, an empty
    cell None).  Read as text only; raises :class:`DkfsimError`."""
    label = str(path)
    lines = _csv_lines(path, what, ["run", "seed", "estimate", "component"], "dkfsim")
    head = next(lines)
    if len(set(head)) != len(head) or any(not c or len(c) > NAME_LIMIT for c in head):
        raise DkfsimError(f"{label}: its header {clip(head)} names a column twice, or "
                          "has an empty or too long name")
    rows: list[dict] = []
    for line, cells in lines:
        if len(cells) != len(head):
            raise DkfsimError(f"{label}: line {line}: {len(cells)} cells for {len(head)} columns")
        rows.append(_row(head, cells, f"{label}: line {line}"))
    return [validate(Row, r, f"{label} (row {i + 1})").model_dump() for i, r in enumerate(rows)]


def _row(head, cells, where: str) -> dict:
    """One CSV line as a row: ``run`` and ``seed`` integers, names as text, metrics numbers."""
    out: dict = {}
    for key, cell in zip(head, cells):
        if key in ("estimate", "component"):
            out[key] = cell
            continue
        try:
            out[key] = (int(cell) if key in ("run", "seed") else
                        None if cell == "" else float(cell))
        except ValueError:
            raise DkfsimError(f"{where}: {clip(key)}: expected a number, got {clip(cell)}") from None
    return out


#: ``curves.npz`` arrays besides ``t``, ``components``, the estimates and ``mse``, with their shapes
#: (``A`` estimates, ``K`` ticks, ``nx`` components).
CURVES = {"mse_ci_lo": "AKX", "mse_ci_hi": "AKX", "example_truth": "KX", "example_x": "AKX",
          "example_node0": "KX", "nees": "AK", "nees_band": "2"}


def read_curves(path, steps: int | None = None, components=None) -> dict:
    """The arrays of a Monte Carlo ``curves.npz``, every header checked (numbers, names,
    shapes) before any data is read.  ``components`` and ``estimates`` come back as lists of
    names (older folders' ``algorithms`` under today's names); ``steps`` and ``components``
    (from ``summary.json``), when given, must match.  Raises :class:`DkfsimError`."""
    with NpzFile(path, "curves.npz") as z:
        K = npz_header(z, "t", (steps,)).shape[0]
        nx = npz_header(z, "components", (None,), kind="name").shape[0]
        key = "estimates" if "estimates" in z else "algorithms"      # (older folders)
        A = npz_header(z, key, (None,), kind="name").shape[0]
        npz_header(z, "mse", (A, K, nx))
        wanted = ["t", "components", key, "mse"]
        size = {"A": A, "K": K, "X": nx, "2": 2}
        for k, dims in CURVES.items():
            if k in z:
                npz_header(z, k, tuple(size[d] for d in dims))
                wanted.append(k)
        arrays: dict[str, Any] = dict(z.read(wanted))
        arrays["components"] = npz_names(z, arrays, "components")
        names = npz_names(z, arrays, key)
        arrays.pop(key)
        arrays["estimates"] = [OLD_NAMES.get(a, a) if key == "algorithms" else a for a in names]
    if components not in (None, arrays["components"]):
        raise DkfsimError(f"{path}: its components {clip(arrays['components'])} are not those of "
                          f"summary.json ({clip(components)})")
    return arrays


# =========================================================================== npz headers
def npz_header(z: NpzFile, key: str, shape=None, kind: str = "number"):
    """The header of array ``key``: present, of ``kind`` ("number": bool, integer or float;
    "name": strings of at most NAME_LIMIT characters) and of ``shape`` (None: any size;
    every size at least 1)."""
    if key not in z:
        raise DkfsimError(f"{z.path}: no array {key!r}")
    h = z.headers[key]
    if kind == "number" and not h.numeric:
        raise DkfsimError(f"{z.path}: array {clip(key)} holds {h.dtype} values, expected numbers")
    if kind == "name" and (h.dtype.kind != "U" or h.dtype.itemsize > 4 * NAME_LIMIT):
        raise DkfsimError(f"{z.path}: array {clip(key)} holds {h.dtype} values, expected names "
                          f"(text of at most {NAME_LIMIT} characters)")
    if shape is not None:
        ok = len(h.shape) == len(shape) and all(s is None or s == d for s, d in zip(shape, h.shape))
        if not ok:
            want = "(" + ", ".join("?" if s is None else str(s) for s in shape) + ")"
            raise DkfsimError(f"{z.path}: array {clip(key)} has shape {h.shape}, expected {want}")
    if 0 in h.shape:
        raise DkfsimError(f"{z.path}: array {clip(key)} is empty (shape {h.shape})")
    return h


def npz_names(z: NpzFile, arrays: dict, key: str) -> list[str]:
    names = [str(v) for v in arrays[key]]
    for v in names:
        if not v.strip():
            raise DkfsimError(f"{z.path}: array {key!r} holds an empty name")
    if len(set(names)) != len(names):
        raise DkfsimError(f"{z.path}: array {key!r} names one thing twice ({clip(names)})")
    return names
