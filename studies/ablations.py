"""Study: the paper's Table 2. Each row's odometer is trained, scored per step on test episodes and
driven through PointGoal navigation, and its numbers are set beside the paper's.

    python -m studies.ablations [--scale ci|cpu|paper] [--out reports/ablations] [--ray-address ADDR] [--redraw]

A row is DeepVO (row 0), the robust VO with the paper's switches (rows 1-18: a recipe with
``path=value`` changes, see ``studies/ablations.toml``) or ground truth (row 20); row 19 is left out
(it fine-tunes the paper's learned policy; odolab's policy is a classical one). Row 21 is not the
paper's: the action prior (each action's mean motion), the floor a trained odometer has to beat. Three phases of
units, each a Ray task whose result is saved as it finishes and reused while its key (everything it
depends on) stays the same: training a row's model (``<out>/models/<row>/model.pt``), its per-step
error on each seed's test episodes (``run_comparison``, the challenge's noise), and its navigation
of each episode (success, SPL, distance to the goal at the end d_G, SoftSPL). The error and
navigation keys hold the model file's SHA-256, so a retrained model is evaluated again. Errors are
mean absolute errors of (dx m, dz m, dyaw rad) x 1e-2 on open-loop test episodes, the paper's on its
navigation steps; our models are trained on a small budget on our simulator: the rows' order against
row 18 is what compares, not the values.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import json
import math
import os
import re
import shutil
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from odolab.config import check, setting
from odolab.sim.scenes import MAX_EPISODE_STEPS
from studies import framework

if TYPE_CHECKING:
    from odolab.core.parallel import Execution
    from odolab.learned.deepvo.config import DeepVOTraining
    from odolab.learned.robust_vo.config import TrainConfig

NAME = "ablations"
DEFINITION = framework.HERE / f"{NAME}.toml"
#: The repository's root, which the recipe paths of the definition start from.
ROOT = framework.HERE.parent
COMPONENTS = ("dx", "dz", "dyaw")
#: Folders under ``<out>`` the study writes besides its results and report.
FOLDERS = ("models", "work", "training", "data")
#: The row the others are compared with (the paper's full model without policy tuning).
REFERENCE_ROW = 18
#: The study's three phases, in the order they run.
PHASES = ("training", "error", "navigation")
#: The paper's switch columns, in its order.
SWITCH_COLUMNS = ("Visual", "DD", "S-proj", "Dropout", "ActInfo", "DataAug", "GeoInv")
VISUAL = {"RGB": "rgb", "D": "depth", "RGB-D": "rgbd"}
ACTINFO = {"none": "unified", "Embed": "actembed", "SepAct": "sepact"}


# ------------------------------------------------------------------------------------ definition


@dataclass(frozen=True)
class Switches:
    """A robust-VO row's switches as the paper's columns name them."""

    visual: Literal["RGB", "D", "RGB-D"]
    dd: int
    sproj: bool
    dropout: bool
    actinfo: Literal["none", "Embed", "SepAct"]
    data_aug: bool
    geoinv: bool

    def text(self) -> str:
        """``RGB-D, DD 10, S-proj, Dropout, SepAct, DataAug, GeoInv``: the switches that are on."""
        parts = [self.visual, f"DD {self.dd}" if self.dd else ""]
        parts += [name for name, on in (("S-proj", self.sproj), ("Dropout", self.dropout)) if on]
        parts += [self.actinfo if self.actinfo != "none" else ""]
        parts += [name for name, on in (("DataAug", self.data_aug), ("GeoInv", self.geoinv)) if on]
        return ", ".join(p for p in parts if p)


@dataclass(frozen=True)
class Paper:
    """The paper's numbers for a row: success, SPL and SoftSPL in %, d_G in m, the per-step error
    (dx m, dz m, dyaw rad) x 1e-2 (none for ground truth), #param in M as the paper writes it."""

    success: float
    spl: float
    d_g: float
    soft_spl: float
    params: str
    error: tuple[float, ...] = ()


#: The paper's numbers of a row the paper does not have: none (NaN; shown as -).
NO_PAPER = Paper(success=math.nan, spl=math.nan, d_g=math.nan, soft_spl=math.nan, params="")


@dataclass(frozen=True)
class Row:
    """One row of the table: its ``odometer``; for the robust VO its ``switches`` and the recipe
    ``changes`` that set them (``wide``: also the scale's ``wide_changes``); ``model_of``: use that
    row's model instead of training one; ``options``: odometer options beyond the model file;
    ``note``: where odolab's row is not the paper's exactly; ``paper`` None: a reference row of
    odolab's that the paper's table does not have (the action prior)."""

    row: int
    paper: Paper | None = None
    odometer: Literal["robust-vo", "deepvo", "ground-truth", "action-prior"] = "robust-vo"
    switches: Switches | None = None
    changes: tuple[str, ...] = ()
    wide: bool = False
    model_of: int | None = None
    options: dict[str, Any] = field(default_factory=dict)
    note: str = ""

    def setting(self) -> str:
        """The row's odometer in words: ``DeepVO``, ``robust VO`` (``rnd10``: ten dropout passes;
        ``2x wide``), ``Ground truth``, ``Action prior``; its switches are :meth:`switch_cells`."""
        named = {"deepvo": "DeepVO", "ground-truth": "Ground truth", "action-prior": "Action prior"}
        if self.odometer in named:
            return named[self.odometer]
        extra = " (rnd10)" if self.options.get("mc_samples") == 10 else ""
        return "robust VO" + extra + (" (2x wide)" if self.wide else "")

    def switch_cells(self) -> dict[str, str]:
        """The paper's switch columns (:data:`SWITCH_COLUMNS`): the visual input, the DD bins, the
        action information and a check mark per switch that is on; empty for the other odometers."""
        s = self.switches
        if s is None:
            return dict.fromkeys(SWITCH_COLUMNS, "")
        marks = {"S-proj": s.sproj, "Dropout": s.dropout, "DataAug": s.data_aug, "GeoInv": s.geoinv}
        return {
            "Visual": s.visual,
            "DD": str(s.dd) if s.dd else "",
            "ActInfo": "" if s.actinfo == "none" else s.actinfo,
            **{k: "\u2713" if on else "" for k, on in marks.items()},
        }


@dataclass(frozen=True)
class Scale:
    """One scale's parameters (see ``studies/ablations.toml``). ``data_root`` "" is ``<out>/data``;
    ``device`` "" is a GPU where the unit sees one, else the CPU; ``train_threads`` 0 leaves torch's
    thread count as it is; ``train_gpus``: GPUs each training unit asks Ray for (0: none, and a unit
    sees every GPU of its node); ``train_seed_rows`` are trained once more for each of
    ``train_seeds`` (the recipe's ``seed`` changed), so the table shows the training-seed spread."""

    rows: tuple[int, ...] = setting(min_items=1, distinct=True, doc="the table's rows, by number")
    robust_vo_recipe: str = setting(doc="the robust-VO rows' recipe (a TOML file)")
    robust_vo_changes: tuple[str, ...] = setting(doc="key=value changes to that recipe")
    sepact_stages: tuple[dict[str, Any], ...] = setting(doc="the SepAct rows' stages")
    single_stages: tuple[dict[str, Any], ...] = setting(doc="the one-network rows' stages")
    wide_changes: tuple[str, ...] = setting(doc="the wide rows' changes")
    deepvo_recipe: str = setting(doc="DeepVO's recipe (a TOML file)")
    deepvo_changes: tuple[str, ...] = setting(doc="key=value changes to it")
    data_root: str = setting(doc='the training data\'s folder ("": <out>/data)')
    device: str = setting(doc='where a unit trains ("": a GPU where it sees one, else the CPU)')
    train_threads: int = setting(range=(0, 1024), doc="torch threads per training unit (0: as it is)")
    seeds: tuple[int, ...] = setting(range=(0, 2**32 - 1), min_items=1, distinct=True, doc="per-step error seeds")
    episodes: int = setting(range=(1, 1000), doc="per-step error episodes per seed")
    max_steps: int = setting(range=(1, MAX_EPISODE_STEPS), doc="per-step error steps per episode at most")
    nav_seeds: tuple[int, ...] = setting(range=(0, 2**32 - 1), min_items=1, distinct=True, doc="navigation seeds")
    nav_episodes: int = setting(range=(1, 1000), doc="navigation episodes per seed")
    nav_max_steps: int = setting(range=(1, MAX_EPISODE_STEPS), doc="actions per navigation episode at most")
    train_gpus: float = setting(0.0, doc="GPUs each training unit asks Ray for (0: none)")
    train_seed_rows: tuple[int, ...] = setting((), distinct=True, doc="rows trained under the further seeds too")
    train_seeds: tuple[int, ...] = setting((), range=(0, 2**32 - 1), distinct=True, doc="the further training seeds")

    def __post_init__(self) -> None:
        check(self)
        if bool(self.train_seed_rows) != bool(self.train_seeds):
            raise ValueError(
                f"train_seeds must be given with train_seed_rows (both or neither), "
                f"got {list(self.train_seeds)} for rows {list(self.train_seed_rows)}"
            )
        if not set(self.train_seed_rows) <= set(self.rows):
            raise ValueError(f"train_seed_rows must be rows of the scale, got {list(self.train_seed_rows)}")
        if not (self.train_gpus == 0 or (math.isfinite(self.train_gpus) and 1e-4 <= self.train_gpus <= 64)):
            raise ValueError(f"train_gpus must be 0 (none) or a number in [0.0001, 64], got {self.train_gpus}")
        if self.device and not re.fullmatch(r"(cpu|cuda|mps|xpu)(:\d+)?", self.device):
            raise ValueError(
                'device must be "" (a GPU where a unit sees one, else the CPU) or a torch device '
                f'such as "cpu" or "cuda:0", got {self.device!r}'
            )
        if self.train_gpus and self.device == "cpu":
            raise ValueError(f'device "cpu" with train_gpus {self.train_gpus:g} asks Ray for GPUs it would not use')
        if self.train_gpus and re.fullmatch(r"cuda:[1-9]\d*", self.device):
            raise ValueError(
                f'device {self.device!r} with train_gpus: a unit sees only the GPU Ray gives it; use "cuda" or ""'
            )


@dataclass(frozen=True)
class Definition:
    """The study: its framework definition (name, title, scales as plain TOML), the changes every
    robust-VO row starts from (``blank``), those of the rows that know the action (``knows_action``:
    ActInfo Embed or SepAct) and of the SepAct rows (``sepact``), the rows by number and each
    scale's parameters."""

    study: framework.StudyConfig
    blank: tuple[str, ...]
    knows_action: tuple[str, ...]
    sepact: tuple[str, ...]
    rows: dict[int, Row]
    scales: dict[str, Scale]
    source: Path = DEFINITION


def load_definition(path: Path = DEFINITION) -> Definition:
    """Read ``studies/ablations.toml``: ``title``, ``blank``, ``knows_action``, ``sepact``,
    ``[scales.*]`` and ``[[rows]]``.
    :class:`odolab.config.ConfigError` names the file and the field. (The rows are the same at every
    scale, so they sit beside the scales rather than in them, where ``framework.load_study`` reads.)"""
    from odolab.config import ConfigError, build, read_toml

    doc = read_toml(path)
    fields = {"title", "blank", "knows_action", "sepact", "scales", "rows"}
    if set(doc) != fields:
        raise ConfigError(f"{path}: expected the fields {', '.join(sorted(fields))}, got {', '.join(sorted(doc))}")
    raw = doc["scales"]
    if not isinstance(raw, dict) or not set(framework.SCALES) <= set(raw) or not all(map(_scale_name, raw)):
        raise ConfigError(
            f"{path}: scales: expected the tables {', '.join(framework.SCALES)} and any named cpu-<name>"
            + (f", got {', '.join(sorted(raw))}" if isinstance(raw, dict) else "")
        )
    scales = {s: build(Scale, raw[s], f"{path}: scales.{s}") for s in raw}
    if not isinstance(doc["rows"], list) or not doc["rows"]:
        raise ConfigError(f"{path}: rows: expected [[rows]] tables")
    rows = [build(Row, r, f"{path}: {_row_place(r, k)}") for k, r in enumerate(doc["rows"])]
    by_number = {r.row: r for r in rows}
    if len(by_number) != len(rows):
        twice = sorted({r.row for r in rows if [q.row for q in rows].count(r.row) > 1})
        raise ConfigError(f"{path}: rows: expected one row of each number, got two of {twice[0]}")
    for r in rows:
        if r.switches is not None and r.switches.dd < 0:
            raise ConfigError(
                f"{path}: row {r.row}: switches.dd: expected 0 (none) or a number of bins, got {r.switches.dd}"
            )
        if (r.odometer == "robust-vo") != (r.switches is not None):
            raise ConfigError(f"{path}: row {r.row}: switches are for robust-VO rows, and every one has them")
        if r.odometer == "action-prior" and r.paper is not None:
            raise ConfigError(
                f"{path}: row {r.row}: paper: expected none (the paper has no action-prior row), got a table"
            )
        if r.odometer != "action-prior" and r.paper is None:
            raise ConfigError(f"{path}: row {r.row}: paper: expected the paper's numbers for its row, got none")
        if r.paper is not None and len(r.paper.error) not in (0, len(COMPONENTS)):
            raise ConfigError(
                f"{path}: row {r.row}: paper.error: expected {len(COMPONENTS)} numbers (dx, dz, dyaw) or none, got {len(r.paper.error)}"
            )
        if r.paper is not None:
            _check_paper(f"{path}: row {r.row}: paper", r.paper)
        if r.options or not isinstance(r.options, dict):
            _check_options(path, r)
        if r.model_of == r.row:
            raise ConfigError(
                f"{path}: row {r.row}: model_of: expected another row that trains a model, got its own number"
            )
        if r.model_of is not None and (r.changes or r.wide):
            raise ConfigError(
                f"{path}: row {r.row}: model_of: a row using another's model trains nothing; drop its changes and wide"
            )
        if r.model_of is not None and (
            r.model_of not in by_number
            or by_number[r.model_of].odometer != r.odometer
            or model_row(by_number[r.model_of]) != r.model_of
            or model_row(r) is None
        ):
            raise ConfigError(
                f"{path}: row {r.row}: model_of: expected a row of the same odometer that trains a model, got {r.model_of}"
            )
    for s, scale in scales.items():
        unknown = sorted(set(scale.rows) - set(by_number))
        if unknown:
            raise ConfigError(f"{path}: scales.{s}.rows: no such row {unknown[0]}")
        for r in scale.train_seed_rows:
            if model_row(by_number[r]) != r:
                raise ConfigError(f"{path}: scales.{s}.train_seed_rows: row {r} trains no model of its own")
    header = build(Header, {k: doc[k] for k in ("title", "blank", "knows_action", "sepact")}, str(path))
    study = framework.StudyConfig(NAME, header.title, raw)
    return Definition(study, header.blank, header.knows_action, header.sepact, by_number, scales, path)


def _scale_name(name: str) -> bool:
    """A scale of the definition: ci, cpu, paper, or a further cpu budget named ``cpu-<name>``."""
    return name in framework.SCALES or re.fullmatch(r"cpu-[a-z0-9]+", name) is not None


def default_out(scale: str) -> Path:
    """Where a scale's report goes by default: ``reports/ablations``; ``reports/ablations-<name>`` for ``cpu-<name>``."""
    return Path("reports") / (NAME if scale in framework.SCALES else f"{NAME}-{scale.removeprefix('cpu-')}")


def _check_paper(where: str, paper: Paper) -> None:
    """Refuse, as the file is read, a paper number outside what it measures: success, SPL and
    SoftSPL in [0, 100] %, d_G and the per-step errors >= 0, all finite."""
    from odolab.config import ConfigError

    values = [("success", paper.success, 100.0), ("spl", paper.spl, 100.0), ("soft_spl", paper.soft_spl, 100.0)]
    values += [("d_g", paper.d_g, math.inf)] + [(f"error[{k}]", v, math.inf) for k, v in enumerate(paper.error)]
    for name, value, top in values:
        if not (math.isfinite(value) and 0.0 <= value <= top):
            expected = f"a number in [0, {top:g}]" if math.isfinite(top) else "a finite number >= 0"
            raise ConfigError(f"{where}.{name}: expected {expected}, got {value}")


def _row_place(doc: Any, k: int) -> str:
    """How messages name the ``k``-th ``[[rows]]`` table: ``row N`` by its number, else ``rows[k]``."""
    number = doc.get("row") if isinstance(doc, dict) else None
    return f"row {number}" if isinstance(number, int) and not isinstance(number, bool) else f"rows[{k}]"


def _check_options(path: Path, row: Row) -> None:
    """Refuse, as the file is read, options that are no table or that row's odometer does not take."""
    from odolab.config import ConfigError
    from odolab.odometry.odometer import REGISTRY
    from odolab.odometry.options import OptionError, check_options

    if not isinstance(row.options, dict):
        raise ConfigError(f"{path}: row {row.row}: options: expected a table, got {row.options!r}")
    if "checkpoint" in row.options:
        raise ConfigError(f"{path}: row {row.row}: options: checkpoint is the row's own model file; leave it out")
    try:
        check_options(row.odometer, REGISTRY.resolve(row.odometer), row.options)
    except OptionError as exc:
        raise ConfigError(f"{path}: row {row.row}: options: {exc}") from None


def check_option_values(definition: Definition, number: int) -> None:
    """Refuse row ``number``'s options that its odometer refuses when made (with its shipped model
    in place of the row's own, which the study has not trained yet)."""
    from odolab.config import ConfigError
    from odolab.odometry.odometer import REGISTRY

    row = definition.rows[number]
    if row.options:
        try:
            REGISTRY.load(row.odometer, **row.options)
        except (ValueError, TypeError) as exc:
            raise ConfigError(f"{definition.source}: row {number}: options: {exc}") from None


@dataclass(frozen=True)
class Header:
    """The study's one-line title and the changes its robust-VO rows share (:class:`Definition`)."""

    title: str
    blank: tuple[str, ...]
    knows_action: tuple[str, ...]
    sepact: tuple[str, ...]


# ---------------------------------------------------------------------------------------- recipes


def model_row(row: Row) -> int | None:
    """The row whose model ``row`` runs (its own, or ``model_of``); None for a reference odometer
    (ground truth, the action prior), which has none."""
    if row.odometer in ("ground-truth", "action-prior"):
        return None
    return row.row if row.model_of is None else row.model_of


def recipe(
    definition: Definition, scale: Scale, number: int, data_root: Path, train_seed: int | None = None
) -> TrainConfig | DeepVOTraining:
    """The training recipe of row ``number`` at ``scale`` (a robust-VO ``TrainConfig`` or DeepVO's
    ``DeepVOTraining``), its data under ``data_root``: the scale's recipe read as a TOML document
    (for the robust VO with the scale's stage schedule in place of its stages), with the scale's,
    the blank row's, the shared ones of a row that knows the action and of a SepAct row, and the
    row's own changes applied in order (then ``seed=train_seed`` where one is given), then built
    and checked."""
    from odolab.config import ChangeError, ConfigError, build, change_document, read_toml

    row = definition.rows[number]
    if row.odometer == "deepvo":
        from odolab.learned.deepvo.config import DeepVOTraining

        path, cls, changes = scale.deepvo_recipe, DeepVOTraining, (*scale.deepvo_changes, *row.changes)
        doc = read_toml(ROOT / path)
    else:
        from odolab.learned.robust_vo.config import TrainConfig

        assert row.switches is not None
        path, cls = scale.robust_vo_recipe, TrainConfig
        actinfo = row.switches.actinfo
        changes = (
            *scale.robust_vo_changes,
            *definition.blank,
            *(definition.knows_action if actinfo != "none" else ()),
            *(definition.sepact if actinfo == "SepAct" else ()),
            *(scale.wide_changes if row.wide else ()),
            *row.changes,
        )
        doc = read_toml(ROOT / path)
        doc["stages"] = list(scale.sepact_stages if row.switches.actinfo == "SepAct" else scale.single_stages)
    changes = (*changes, *(() if train_seed is None else (f"seed={train_seed}",)))
    doc["data_root"] = str(data_root)
    where = f"{definition.source}: row {number}'s recipe ({path} with the scale's and the row's changes)"
    try:
        changed = change_document(doc, changes)
    except ChangeError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    return build(cls, changed, where)


def trained_switches(cfg: TrainConfig) -> Switches:
    """The paper's switches that robust-VO recipe ``cfg`` trains: its model's visual input, DD bins,
    S-proj, dropout (> 0) and kind (action information), and whether any stage uses DataAug or GeoInv."""
    m = cfg.model
    return Switches(
        visual={"rgb": "RGB", "depth": "D", "rgbd": "RGB-D"}[m.visual],
        dd=m.dd_bins,
        sproj=m.sproj,
        dropout=m.dropout > 0,
        actinfo={"unified": "none", "actembed": "Embed", "sepact": "SepAct"}[m.kind],
        data_aug=any(stage.data_aug for stage in cfg.stages),
        geoinv=any(stage.geoinv for stage in cfg.stages),
    )


def check_switches(definition: Definition, number: int, cfg: TrainConfig) -> None:
    """Refuse row ``number`` when the switches its table shows are not those its recipe ``cfg`` trains."""
    from odolab.config import ConfigError

    shown, trained = definition.rows[number].switches, trained_switches(cfg)
    for f in dataclasses.fields(Switches):
        if shown is not None and getattr(shown, f.name) != getattr(trained, f.name):
            raise ConfigError(
                f"{definition.source}: row {number}: switches.{f.name}: the table would show "
                f"{getattr(shown, f.name)!r}, but the row's recipe trains {getattr(trained, f.name)!r}"
            )


def recipe_identity(cfg: TrainConfig | DeepVOTraining) -> dict[str, Any]:
    """What a model depends on: the whole recipe but where its data live and how it computes. A data
    set's ``clean_depth`` is left out while False (the data are then those made before the setting
    existed, as their folder's digest has it), so results saved before it came still match."""
    doc = json.loads(json.dumps(dataclasses.asdict(cfg)))
    del doc["data_root"], doc["compute"]
    for data in ("train_data", "val_data"):
        if doc.get(data, {}).get("clean_depth") is False:
            del doc[data]["clean_depth"]
    return doc


def data_root(scale: Scale, out: Path) -> Path:
    """The folder of the scale's training data: its ``data_root``, or ``<out>/data`` for ""."""
    return out / "data" if scale.data_root == "" else Path(scale.data_root)


# ------------------------------------------------------------------------------------------ units


@contextlib.contextmanager
def torch_threads(threads: int) -> Iterator[None]:
    """torch on ``threads`` threads for the block (0: as it is), restored after: two threads beside
    other busy processes on two cores wait on each other far more than one works alone."""
    import torch

    before = torch.get_num_threads()
    if threads:
        torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def train_row(
    key: dict[str, Any],
    *,
    out: Path,
    recipes: dict[tuple[int, int | None], TrainConfig | DeepVOTraining],
    device: str,
    threads: int,
) -> dict[str, Any]:
    """Train (or resume, or only export) row ``key["row"]``'s model (with ``key["train_seed"]``: its
    run of that seed) with its family's own trainer: work states in :func:`work_folder`, curves under ``<out>/training/<model>``, the model at :func:`model_file`, where
    <model> is :func:`model_id`; returns :func:`model_summary`."""
    from odolab.core.parallel import SERIAL
    from odolab.learned.training import pick_device
    from odolab.learned.training.checkpoints import what_file

    number, seed = key["row"], key.get("train_seed")
    cfg, name = recipes[(number, seed)], model_id(number, seed)
    if recipe_identity(cfg) != key["recipe"]:
        raise ValueError(f"row {number}: the recipe handed over is not the unit's")
    if key["family"] == "deepvo":
        from odolab.learned.deepvo.train import run
    else:
        from odolab.learned.robust_vo.train import run
    export = out / model_file(number, seed)
    if export.is_file() and not export.is_symlink() and what_file(export) is not None:
        export.unlink()  # the study's own model path holds no model (a damaged file): export it again
    with torch_threads(threads):
        done = run(
            cfg,
            work=work_folder(out, key),
            reports=out / "training" / name,
            export=export,
            device=pick_device(device or None),
            hours=None,
            execution=SERIAL,
        )
    if not done:
        raise RuntimeError(f"row {number}: training stopped before its last epoch")
    return model_summary(export, key["family"], out)


def work_folder(out: Path, key: dict[str, Any]) -> Path:
    """A training unit's states (one file per stage, saved every epoch and within one):
    ``<out>/work/<model>/<key digest>``, <model> as :func:`model_id` names it."""
    return out / "work" / model_id(key["row"], key.get("train_seed")) / framework.Unit("", key).digest


def check_states(units: Sequence[framework.Unit], out: Path) -> None:
    """``UsageError`` naming the first training state of ``units`` that cannot be read (damaged,
    cut short, or another file under its name), before any data is made or training starts."""
    from odolab.cli import UsageError
    from odolab.learned.training.checkpoints import load_checkpoint
    from odolab.learned.training.epochs import STATE_FORMAT, STATE_KIND

    for u in units:
        folder = work_folder(out, u.key)
        for path in sorted(folder.glob("*.pt")) if folder.is_dir() and not folder.is_symlink() else ():
            try:
                load_checkpoint(path, STATE_KIND, STATE_FORMAT)
            except ValueError as exc:
                raise UsageError(f"{exc}; delete it to train that stage of {u.label} again") from None


def say_retrained(units: Sequence[framework.Unit], store: framework.ResultStore) -> None:
    """One line for each of ``units`` (models to train) whose result is saved but whose model file is
    missing or changed: training it again (from its saved states, where any are kept) is no surprise."""
    for u in units:
        saved = store.get(u)
        value = saved.get("value") if isinstance(saved, dict) else None
        if valid_model(value, out=Path(), check_file=False):
            print(f"{u.label}: {value['model']} is missing or not the model its saved results came from: trained again")


def drop_finished_states(units: Sequence[framework.Unit], results: dict[str, Any], out: Path) -> None:
    """Remove the training states of ``units`` whose results are saved (in ``results``) and whose model
    files are there as saved: those models hold what the states did, so ``<out>/work`` keeps only
    unfinished models' states (a model being trained again after its file was lost keeps its states
    while a run computes other rows). A folder that cannot be removed is named in one line and kept."""
    for u in units:
        folder = work_folder(out, u.key)
        if u.label not in results or not folder.exists() or folder.is_symlink():
            continue
        if not valid_model(results[u.label], out=out, check_file=True):
            continue
        try:
            shutil.rmtree(folder)
        except OSError as exc:
            print(f"note: {folder}: a finished model's training states, kept ({exc.strerror or exc})")
            continue
        with contextlib.suppress(OSError):  # the model's folder, where it holds nothing else now
            folder.parent.rmdir()


def model_id(number: int, train_seed: int | None = None) -> str:
    """A model's name in the study's folders: ``18``, or ``18-seed1`` for row 18's run of training seed 1."""
    return str(number) if train_seed is None else f"{number}-seed{train_seed}"


def train_label(number: int, train_seed: int | None = None) -> str:
    """A training unit's label: ``train row 18``, or ``train row 18 seed 1``."""
    return f"train row {number}" + ("" if train_seed is None else f" seed {train_seed}")


def model_file(number: int, train_seed: int | None = None) -> str:
    """Where row ``number``'s model (of ``train_seed``'s run) lives, relative to the study's folder."""
    return f"models/{model_id(number, train_seed)}/model.pt"


def model_summary(path: Path, family: str, out: Path) -> dict[str, Any]:
    """A model file's SHA-256, parameters (all networks) and networks, the pairs its training saw
    (a DeepVO window of n frames counts n - 1) and the hours it took."""
    if family == "deepvo":
        from odolab.learned.deepvo.odometer import load_model

        _, net, info = load_model(path)
        nets = [net]
        training = info["training"]
        pairs = int(training.get("windows_seen", 0)) * (int(info["recipe"]["window"]) - 1)
        hours = float(training.get("hours", 0.0))
    else:
        from odolab.learned.robust_vo.checkpoint import load_model

        _, modules, info = load_model(path)
        nets = list(modules.values())
        stages = info["training"].get("stages", {}).values()
        pairs = int(sum(s.get("pairs_seen", 0) for s in stages))
        hours = float(sum(s.get("hours", 0.0) for s in stages))
    return {
        "model": path.relative_to(out).as_posix(),
        "sha256": info["sha256"],
        "parameters": int(sum(p.numel() for n in nets for p in n.parameters())),
        "networks": len(nets),
        "pairs_seen": pairs,
        "training_hours": hours,
    }


def valid_model(value: Any, *, out: Path, check_file: bool) -> bool:
    """Whether a saved training result has :func:`model_summary`'s shape and, with ``check_file``,
    its model file is still there with that SHA-256 (otherwise it is exported or trained again)."""
    ok = (
        isinstance(value, dict)
        and isinstance(value.get("sha256"), str)
        and isinstance(value.get("model"), str)
        and all(isinstance(value.get(k), int) for k in ("parameters", "networks", "pairs_seen"))
        and _number(value.get("training_hours"))
    )
    if not ok or not check_file:
        return ok
    path = out / value["model"]
    return path.is_file() and not path.is_symlink() and _sha256(path) == value["sha256"]


def _sha256(path: Path) -> str:
    """A file's SHA-256 (as the odometers' ``identity_digest``)."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _number(v: Any) -> bool:
    """An int or float that is no bool, no NaN and no infinity."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _odometer(key: dict[str, Any], out: Path) -> tuple[str, dict[str, Any]]:
    """The odometer of an error or navigation unit and its options (the model file's path added),
    refused when the model file is not the one the key names."""
    from odolab.api import load_odometer

    options = dict(key["options"])
    if key["model"]:
        options["checkpoint"] = str(out / key["model"])
    digest = load_odometer(key["odometer"], **options).identity_digest
    if digest != key["sha256"]:
        raise ValueError(f"row {key['row']}: {key['model']} is not the model this unit was made for; run again")
    return key["odometer"], options


class BrokenOdometer(ValueError):
    """An evaluation unit whose row's odometer failed every step (a model its code cannot read, an
    odometer that raises): not a measurement of the row, so nothing is saved and the run stops with
    this one line (a ``ValueError``: raised from a Ray task as itself)."""


def _refuse_unmeasured(
    key: dict[str, Any], name: str, steps: int, all_failed: bool, where: str, said: list[str]
) -> None:
    """:class:`BrokenOdometer` when odometer ``name`` of an evaluation unit's ``key`` failed every one
    of its ``steps`` (``all_failed``) ``where``; the line names the row, the model file it runs (one per
    training seed) and ``said``'s first message (what raised, or the runner's reasons)."""
    if steps and all_failed:
        whose = f"row {key['row']}" + (f" ({key['model']})" if key.get("model") else "")
        raise BrokenOdometer(
            f"{whose}: {name} failed every one of its {steps} steps {where} "
            f"(first: {said[0] if said else 'no message'}); nothing saved for it"
        )


def step_errors(key: dict[str, Any], *, out: Path, cache: Path | None = None) -> dict[str, Any]:
    """One row's odometer on one seed's test episodes: mean absolute error of (dx, dz, dyaw) x 1e-2
    over every step (a failed step scored with the action prior that replaced it) and per episode
    (``episodes``, in episode order: the paired tests' input), steps, failure share, and steps per
    second of the odometer's own ``step`` calls (``fps``); ``cache``: the episode cache (default the
    comparison's)."""
    from odolab.api import SERIAL, ComparisonConfig, run_comparison
    from odolab.sim.episodes import NoiseConfig

    name, options = _odometer(key, out)
    result = run_comparison(
        ComparisonConfig(
            odometers=[name],
            options={name: options},
            episodes=key["episodes"],
            max_steps=key["max_steps"],
            seed=key["seed"],
            split="test",
            noise=NoiseConfig(**key["noise"]),
            cache=cache or framework.episode_cache(key),
            execution=SERIAL,
        )
    )
    from odolab.reporting.pipeline import failure_reasons
    from odolab.running.summary import step_errors as abs_errors

    (row,) = [r for r in result.rows if r.odometer == name]
    mine = [r for r in result.results if r.odometer == name]
    reasons = failure_reasons(mine).get(name, {})
    _refuse_unmeasured(
        key,
        name,
        row.steps,
        row.failure_share == 1.0,
        f"on the seed-{key['seed']} test episodes",
        [e for r in mine for e in r.errors] + [f"{n} step(s) {k}" for k, n in sorted(reasons.items())],
    )
    return {
        **{c: float(getattr(row, c)) for c in COMPONENTS},
        "episodes": [[float(v) for v in abs_errors(r).mean(axis=0) * 100] for r in mine],
        "steps": int(row.steps),
        "failure_share": float(row.failure_share),
        "fps": None if row.reference else float(row.fps),
    }


def valid_errors(value: Any) -> bool:
    """Whether a saved error result has :func:`step_errors`' shape (``fps`` None: ground truth;
    ``episodes`` may be missing: a result saved before they were kept, read without paired tests)."""
    episodes = value.get("episodes", []) if isinstance(value, dict) else None
    return (
        isinstance(value, dict)
        and isinstance(episodes, list)
        and all(isinstance(e, list) and len(e) == len(COMPONENTS) and all(map(_number, e)) for e in episodes)
        and all(_number(value.get(c)) for c in (*COMPONENTS, "failure_share"))
        and isinstance(value.get("steps"), int)
        and (value.get("fps") is None or _number(value.get("fps")))
    )


def navigate_episode(key: dict[str, Any], *, out: Path) -> dict[str, Any]:
    """One row's odometer as the agent's only sense of its motion in one test episode (the default
    policy, the challenge's noise): success (0/1), SPL, SoftSPL, d_G (geodesic distance to the goal
    at the end, m), steps, collisions and failed steps."""
    from odolab.api import load_odometer
    from odolab.navigation.agent import PolicyConfig
    from odolab.navigation.episode import navigate
    from odolab.sim.episodes import EpisodeSpec, NoiseConfig

    name, options = _odometer(key, out)
    spec = EpisodeSpec(
        split="test",
        index=key["episode"],
        seed=key["seed"],
        max_steps=key["max_steps"],
        noise=NoiseConfig(**key["noise"]),
    )
    run = navigate(spec, load_odometer(name, **options), PolicyConfig(**key["policy"]))
    o = run.outcome
    where = f"in test episode {key['episode']} of seed {key['seed']}"
    _refuse_unmeasured(key, name, o.steps, run.failed_steps == o.steps, where, list(run.errors))
    return {
        "success": o.success,
        "spl": o.spl,
        "soft_spl": o.soft_spl,
        "d_g": o.d_end,
        "steps": o.steps,
        "collisions": o.collisions,
        "failed_steps": run.failed_steps,
    }


def valid_navigation(value: Any) -> bool:
    """Whether a saved navigation result has :func:`navigate_episode`'s shape and ranges (SPL and
    SoftSPL in [0, 1], SPL 0 without success, d_G >= 0 m, counts >= 0)."""
    return (
        isinstance(value, dict)
        and value.get("success") in (0, 1)
        and all(_number(value.get(k)) for k in ("spl", "soft_spl", "d_g"))
        and all(0.0 <= value[k] <= 1.0 for k in ("spl", "soft_spl"))
        and (value["spl"] == 0.0 or value["success"] == 1)
        and value["d_g"] >= 0.0
        and all(isinstance(value.get(k), int) and value[k] >= 0 for k in ("steps", "collisions", "failed_steps"))
    )


def train_units(
    definition: Definition, recipes: dict[tuple[int, int | None], TrainConfig | DeepVOTraining]
) -> list[framework.Unit]:
    """One unit per model the scale's rows run (``recipes`` by (row, training seed or None)); its key
    is the whole recipe (data location and compute settings aside) and the training seed's run."""
    return [
        framework.Unit(
            train_label(n, seed),
            {"row": n, "family": definition.rows[n].odometer, "recipe": recipe_identity(cfg)}
            | ({} if seed is None else {"train_seed": seed}),
        )
        for (n, seed), cfg in recipes.items()
    ]


def odometer_key(row: Row, models: dict[str, Any], train_seed: int | None = None) -> dict[str, Any] | None:
    """What a row's evaluations depend on: its odometer, options and model (file and SHA-256; the run
    of ``train_seed`` where one is given); None while the model it runs has no training result."""
    number = model_row(row)
    if number is None:
        return {"row": row.row, "odometer": row.odometer, "options": row.options, "model": "", "sha256": None}
    trained = models.get(train_label(number, train_seed))
    if trained is None:
        return None
    return {
        "row": row.row,
        "odometer": row.odometer,
        "options": row.options,
        "model": trained["model"],
        "sha256": trained["sha256"],
    }


def evaluation_units(
    definition: Definition, scale: Scale, models: dict[str, Any]
) -> tuple[list[framework.Unit], list[framework.Unit], list[str]]:
    """The error units (row x seed) and navigation units (row x seed x episode) of every row whose
    model is trained, and of each further training seed's run of the ``train_seed_rows``
    (:func:`run_label`), and the rows left out for want of a model."""
    from odolab.navigation.agent import PolicyConfig
    from odolab.sim.episodes import NoiseConfig

    noise = dataclasses.asdict(NoiseConfig())
    policy = PolicyConfig().record()
    errors, navigation, untrained = [], [], []
    runs = [(n, None) for n in scale.rows] + [(n, k) for n in scale.train_seed_rows for k in scale.train_seeds]
    for number, train_seed in runs:
        odometer = odometer_key(definition.rows[number], models, train_seed)
        if odometer is None:
            untrained.append(run_label(number, train_seed))
            continue
        for seed in scale.seeds:
            key = {**odometer, "seed": seed, "episodes": scale.episodes, "max_steps": scale.max_steps, "noise": noise}
            errors.append(framework.Unit(f"errors {run_label(number, train_seed)} seed {seed}", key))
        for seed in scale.nav_seeds:
            for episode in range(scale.nav_episodes):
                key = {
                    **odometer,
                    "seed": seed,
                    "episode": episode,
                    "max_steps": scale.nav_max_steps,
                    "noise": noise,
                    "policy": policy,
                }
                label = f"navigate {run_label(number, train_seed)} seed {seed} episode {episode}"
                navigation.append(framework.Unit(label, key))
    return errors, navigation, untrained


def run_label(number: int, train_seed: int | None = None) -> str:
    """How evaluation units name a row's run: ``row 18``, or ``row 18 train seed 1``."""
    return f"row {number}" + ("" if train_seed is None else f" train seed {train_seed}")


# ------------------------------------------------------------------------------------------ table


COLUMNS = [
    "row", "setting", *SWITCH_COLUMNS, "params_M", "paper_params_M",
    "S", "S_ci", "paper_S", "SPL", "SPL_ci", "paper_SPL", "d_G", "d_G_ci", "paper_d_G", "SoftSPL", "SoftSPL_ci",
    "paper_SoftSPL", "dx", "dx_sd", "dz", "dz_sd", "dyaw", "dyaw_sd", "paper_error", "fps", "S_vs_18",
    "error_vs_18", "nav_episodes", "train_seeds", "S_train_sd", "error_train_sd", "pairs_seen", "train_h",
]  # fmt: skip


def _params_text(trained: dict[str, Any] | None) -> str:
    """``3x0.58`` (networks x M each) or ``0.58``, as the paper writes #param."""
    if not trained:
        return ""
    each = trained["parameters"] / trained["networks"] / 1e6
    return f"{trained['networks']}x{each:.2f}" if trained["networks"] > 1 else f"{each:.2f}"


def _interval(low: float, high: float) -> str:
    """``[low, high]`` to one decimal, or "" where there is no interval (one value, or none)."""
    return f"[{low:.1f}, {high:.1f}]" if math.isfinite(low) and math.isfinite(high) else ""


def table(
    definition: Definition, scale: Scale, models: dict[str, Any], errors: dict[str, Any], navigation: dict[str, Any]
) -> list[dict[str, Any]]:
    """One line per row of the scale, laid out as the paper's table (its switch columns first): our
    numbers and the paper's beside them, and whether the row's order against row 18 agrees with the
    paper's. Errors (x 1e-2): mean and standard deviation over the seeds; fps: steps per second of
    the odometer alone, mean over the seeds; navigation (S, SPL, SoftSPL in %, d_G in m): mean over
    every seed's episodes with its 95 % interval (Wilson's for success, Student's t for the others,
    kept within the measure's range: 0-100 %, d_G >= 0). These are of the row's recipe's own
    training run; ``train_seeds`` counts its runs and, over two or more, ``S_train_sd`` and
    ``error_train_sd`` are the standard deviations over the runs of S (%) and of the mean of the
    three errors (x 1e-2), each run on the same seeds and episodes.
    Each line also carries ``S_range``, ``SPL_range``, ``SoftSPL_range``, ``d_G_range`` (the 95 %
    intervals as numbers) and ``error_ci`` (the mean error's interval over the seeds) for the
    verdicts and the figure."""
    from odolab.core.stats import mean_ci

    lines = []
    for number in scale.rows:
        row = definition.rows[number]
        trained = models.get(train_label(model_row(row))) if model_row(row) is not None else None
        got, nav = _run_results(scale, errors, navigation, number)
        runs = [(got, nav)] + [
            _run_results(scale, errors, navigation, number, k)
            for k in scale.train_seeds
            if number in scale.train_seed_rows
        ]
        runs = [(g, n) for g, n in runs if g and n]
        run_s = [100 * float(np.mean([n["success"] for n in nv])) for _, nv in runs]
        run_error = [float(np.mean([[g[c] for c in COMPONENTS] for g in gs])) for gs, _ in runs]
        paper = row.paper or NO_PAPER
        line: dict[str, Any] = {
            "row": number,
            "setting": row.setting(),
            **row.switch_cells(),
            "params_M": "" if model_row(row) is None else _params_text(trained),
            "paper_params_M": paper.params,
            "paper_S": paper.success,
            "paper_SPL": paper.spl,
            "paper_d_G": paper.d_g,
            "paper_SoftSPL": paper.soft_spl,
            "paper_error": f"({', '.join(f'{v:.2f}' for v in paper.error)})" if paper.error else "",
            "paper_error_mean": float(np.mean(paper.error)) if paper.error else float("nan"),
            "paper_errors": tuple(paper.error),  # (dx, dz, dyaw) x 1e-2, or () where the paper has none
            "nav_episodes": len(nav),
            "train_seeds": len(runs) if model_row(row) is not None else "",
            "S_train_sd": float(np.std(run_s, ddof=1)) if len(runs) > 1 else "",
            "error_train_sd": float(np.std(run_error, ddof=1)) if len(runs) > 1 else "",
            "pairs_seen": trained["pairs_seen"] if trained and row.model_of is None else "",
            "train_h": trained["training_hours"] if trained and row.model_of is None else "",
        }
        for c in COMPONENTS:
            values = [g[c] for g in got]
            line[c] = float(np.mean(values)) if values else float("nan")
            line[f"{c}_sd"] = float(np.std(values, ddof=1)) if len(values) > 1 else float("nan")
        line["error_ci"] = mean_ci(np.array([np.mean([g[c] for c in COMPONENTS]) for g in got]))
        speeds = [g["fps"] for g in got if g.get("fps") is not None]
        line["fps"] = float(np.mean(speeds)) if speeds else float("nan")
        for column, k, scale_by, binary in (
            ("S", "success", 100, True),
            ("SPL", "spl", 100, False),
            ("SoftSPL", "soft_spl", 100, False),
            ("d_G", "d_g", 1, False),
        ):
            ci = mean_ci(np.array([n[k] for n in nav], float), binary=binary)
            top = np.inf if k == "d_g" else 1.0  # the interval stays where the measure can be
            low, high = (float(np.clip(b, 0.0, top)) * scale_by for b in (ci.low, ci.high))
            line[column] = ci.mean * scale_by
            line[f"{column}_ci"] = _interval(low, high)
            line[f"{column}_range"] = (low, high)
        lines.append(line)
    reference = next((line for line in lines if line["row"] == REFERENCE_ROW), None)
    paper_reference = definition.rows[REFERENCE_ROW].paper
    assert paper_reference is not None  # load_definition checks it
    for line in lines:
        paper = definition.rows[line["row"]].paper or NO_PAPER
        line["S_vs_18"] = _order(
            line["S"],
            reference and reference["S"],
            paper.success,
            paper_reference.success,
            overlap=reference is not None and _overlap(line["S_range"], reference["S_range"]),
        )
        line["error_vs_18"] = _order(
            -_mean_error(line),
            reference and -_mean_error(reference),
            -line["paper_error_mean"] if paper.error else None,
            -float(np.mean(paper_reference.error)),
            overlap=reference is not None
            and _overlap(
                (line["error_ci"].low, line["error_ci"].high), (reference["error_ci"].low, reference["error_ci"].high)
            ),
        )
        if line["row"] == REFERENCE_ROW:
            line["S_vs_18"] = line["error_vs_18"] = ""
    return lines


def _run_results(
    scale: Scale, errors: dict[str, Any], navigation: dict[str, Any], number: int, train_seed: int | None = None
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """One run's saved error results (per seed) and navigation results (per seed and episode)."""
    run = run_label(number, train_seed)
    got = [errors[label] for s in scale.seeds if (label := f"errors {run} seed {s}") in errors]
    nav = [
        navigation[label]
        for s in scale.nav_seeds
        for e in range(scale.nav_episodes)
        if (label := f"navigate {run} seed {s} episode {e}") in navigation
    ]
    return got, nav


def _overlap(a: tuple[float, float], b: tuple[float, float]) -> bool:
    """Whether two intervals share a point; True when either is unknown (NaN: one value or none)."""
    if not all(math.isfinite(v) for v in (*a, *b)):
        return True
    return a[0] <= b[1] and b[0] <= a[1]


def _mean_error(line: dict[str, Any]) -> float:
    """The mean of a line's three error components (x 1e-2)."""
    return float(np.mean([line[c] for c in COMPONENTS]))


def _order(ours: float, ours_ref: float | None, paper: float | None, paper_ref: float, overlap: bool = False) -> str:
    """Whether ours is above, below or level with row 18 as the paper's is (higher is better):
    ``agrees``, ``differs``, ``tie`` (ours level with row 18's, the paper's not), or "" without
    numbers; `` (overlap)`` follows when our 95 % intervals of the two rows overlap (the order is
    not settled at this sample size)."""
    if paper is None or ours_ref is None or not all(map(math.isfinite, (ours, ours_ref, paper))):
        return ""
    mine, theirs = np.sign(ours - ours_ref), np.sign(paper - paper_ref)
    if mine == 0 and theirs != 0:
        return "tie"
    return ("agrees" if mine == theirs else "differs") + (" (overlap)" if overlap else "")


def _for_seeds(seeds: Sequence[int]) -> str:
    """``for the seed 0`` or ``for each of the seeds 0, 1, 2``."""
    listed = ", ".join(map(str, seeds))
    return f"for the seed {listed}" if len(seeds) == 1 else f"for each of the seeds {listed}"


def findings(lines: list[dict[str, Any]]) -> list[str]:
    """Per measure, which rows come on the same side of row 18 as in the paper, and of those which
    are apart from row 18 by more than our 95 % intervals."""
    from odolab.reporting.report import counted

    out = []
    for column, measure in (("S_vs_18", "Success"), ("error_vs_18", "Per-step error (mean of dx, dz, dyaw)")):
        said = {
            v: [str(line["row"]) for line in lines if line[column].split(" ")[0] == v]
            for v in ("agrees", "differs", "tie")
        }
        clear = [str(line["row"]) for line in lines if line[column] in ("agrees", "differs")]
        judged = sum(map(len, said.values()))
        if not judged:
            out.append(f"{measure}: no row to set against row 18 (row 18 or the numbers are missing)")
            continue
        out.append(
            f"{measure} against row 18: ours on the paper's side in {len(said['agrees'])} of {counted(judged, 'row')}"
            f" ({', '.join(said['agrees']) or 'none'}); the other side in {', '.join(said['differs']) or 'none'}; "
            f"level with row 18 in {', '.join(said['tie']) or 'none'}. Apart from row 18 beyond our 95 % "
            f"intervals: {', '.join(clear) or 'none'}"
        )
    return out


#: The settings of the rows that are references rather than trained odometers.
REFERENCES = ("Ground truth", "Action prior")


def floor_findings(lines: list[dict[str, Any]]) -> list[str]:
    """Which trained rows beat the action prior (the floor), per error component and per navigation
    measure: an error below the prior's by more than both rows' standard deviations over the seeds
    (mean + sd of the row under mean - sd of the prior); a navigation measure better than the
    prior's with the two 95 % intervals apart. Empty without an action-prior line."""
    prior = next((line for line in lines if line["setting"] == "Action prior"), None)
    if prior is None:
        return []
    trained = [line for line in lines if line["setting"] not in REFERENCES]

    def sd(line: dict[str, Any], c: str) -> float:
        return line[f"{c}_sd"] if math.isfinite(line[f"{c}_sd"]) else 0.0

    def rows(picked: list[dict[str, Any]]) -> str:
        return ", ".join(str(line["row"]) for line in picked) or "none"

    said = []
    if math.isfinite(prior["dx"]):
        below = {c: [ln for ln in trained if ln[c] + sd(ln, c) < prior[c] - sd(prior, c)] for c in COMPONENTS}
        said.append(
            f"Per-step error against the action prior (row {prior['row']}: {', '.join(f'{c} {prior[c]:.2f}' for c in COMPONENTS)}"
            f"), rows below it by more than both rows' standard deviations over the seeds"
            f"{'' if math.isfinite(prior['dx_sd']) else ' (one seed: no standard deviation, so simply below)'}: {'; '.join(f'{c}: {rows(below[c])}' for c in COMPONENTS)}"
        )
    if math.isfinite(prior["S"]):
        better = {
            column: [
                ln
                for ln in trained
                if all(map(math.isfinite, (*ln[f"{column}_range"], *prior[f"{column}_range"])))
                and (
                    ln[f"{column}_range"][1] < prior[f"{column}_range"][0]
                    if column == "d_G"
                    else ln[f"{column}_range"][0] > prior[f"{column}_range"][1]
                )
            ]
            for column in ("S", "SPL", "SoftSPL", "d_G")
        }
        said.append(
            f"Navigation against the action prior (S {prior['S']:.0f} %, SoftSPL {prior['SoftSPL']:.0f} %, "
            f"d_G {prior['d_G']:.2f} m), rows better with the two 95 % intervals apart: "
            + "; ".join(f"{column}: {rows(better[column])}" for column in better)
        )
    return said


def claim_findings(lines: list[dict[str, Any]]) -> list[str]:
    """The paper's claim that a lower per-step error gives better navigation, as Spearman's rank
    correlation between the mean per-step error and S, SoftSPL and d_G: over the trained rows (the
    references left out), then over the SepAct rows alone (a correlation over all rows may come from
    one split, the rows that know the action against those that do not); ours, and the paper's over
    the same rows. A group below three rows says nothing."""
    from scipy.stats import spearmanr

    said = []
    for group, picked in (
        ("", lambda line: line["setting"] not in REFERENCES),
        (" over the SepAct rows only", lambda line: line.get("ActInfo") == "SepAct"),
    ):
        for who, error, columns in (
            ("ours", _mean_error, ("S", "SoftSPL", "d_G")),
            ("the paper's", lambda line: line["paper_error_mean"], ("paper_S", "paper_SoftSPL", "paper_d_G")),
        ):
            parts = []
            for column in columns:
                got = [
                    (error(line), line[column])
                    for line in lines
                    if picked(line) and math.isfinite(error(line)) and math.isfinite(line[column])
                ]
                if len(got) >= 3 and len({x for x, _ in got}) > 1 and len({y for _, y in got}) > 1:
                    rho = spearmanr(*zip(*got)).statistic
                    parts.append(f"{column.removeprefix('paper_')} {rho:+.2f} ({len(got)} rows)")
            if parts:
                said.append(
                    f"Mean per-step error against navigation, Spearman's rank correlation{group}, {who}: {', '.join(parts)}"
                )
    return said


#: The paper's pairwise claims about its Table 2 (its Sec. 5): (row, the row it improves on).
CLAIMS = ((3, 1), (3, 2), (4, 3), (7, 6), (8, 7), (10, 8), (13, 10), (18, 13), (18, 15), (18, 16))
#: The family-wise error rate of the claims' tests (Holm's correction over every test of the table).
ALPHA = 0.05
CLAIM_COLUMNS = [
    "claim", "measure", "paper_a", "paper_b", "ours_a", "ours_b", "tested_over", "pairs", "a_only", "b_only", "diff",
    "p", "p_holm", "verdict",
]  # fmt: skip
#: The test of a claim whose two rows were both trained under several seeds: over the training runs.
OVER_RUNS = (
    "Student's paired t test of the per-training-run means (the runs of one seed index paired; no test where "
    "every run's difference is the same, as a few runs then give no spread)"
)
#: What each measure of a claim is: its unit, whether higher is better, and the test.
CLAIM_MEASURES = {
    "success": ("%", True, "McNemar's exact test on the shared episodes"),
    "SPL": ("%", True, "Student's paired t test on the shared episodes"),
    "error": ("x 1e-2", False, "Student's paired t test of the mean of dx, dz, dyaw per shared episode"),
}


def _paired_values(
    scale: Scale,
    errors: dict[str, Any],
    navigation: dict[str, Any],
    rows: tuple[int, int],
    measure: str,
    runs: tuple[int | None, int | None] = (None, None),
) -> tuple[np.ndarray, np.ndarray]:
    """Both rows' values on the trials both have: per (seed, episode) success or SPL (0-1) of the
    navigation units, or the mean of the three error components (x 1e-2) per error episode; ``runs``:
    each row's training run (None: its main one, else the further training seed)."""
    a, b = [], []
    labels = [run_label(r, k) for r, k in zip(rows, runs)]
    if measure == "error":
        for seed in scale.seeds:
            got = [errors.get(f"errors {label} seed {seed}", {}).get("episodes") for label in labels]
            if all(got) and len(got[0]) == len(got[1]):
                a += [float(np.mean(e)) for e in got[0]]
                b += [float(np.mean(e)) for e in got[1]]
        return np.array(a), np.array(b)
    key = "success" if measure == "success" else "spl"
    for seed in scale.nav_seeds:
        for e in range(scale.nav_episodes):
            got = [navigation.get(f"navigate {label} seed {seed} episode {e}") for label in labels]
            if all(got):
                a.append(float(got[0][key]))
                b.append(float(got[1][key]))
    return np.array(a), np.array(b)


def _paper_value(definition: Definition, row: int, measure: str) -> float:
    paper = definition.rows[row].paper or NO_PAPER
    if measure == "error":
        return float(np.mean(paper.error)) if paper.error else math.nan
    return float(paper.success if measure == "success" else paper.spl)


def _training_runs(scale: Scale, row: int) -> list[int | None]:
    """A row's training runs: its main one (None), then the further training seeds where it has them."""
    return [None, *scale.train_seeds] if row in scale.train_seed_rows else [None]


def _run_means(
    scale: Scale, errors: dict[str, Any], navigation: dict[str, Any], rows: tuple[int, int], measure: str
) -> tuple[np.ndarray, np.ndarray]:
    """Per training run (the runs of one seed index paired), both rows' mean value on the trials
    those two runs share (success and SPL 0-1, error x 1e-2); runs with no shared trial are left out."""
    pairs = [
        _paired_values(scale, errors, navigation, rows, measure, runs)
        for runs in zip(_training_runs(scale, rows[0]), _training_runs(scale, rows[1]))
    ]
    kept = [(a.mean(), b.mean()) for a, b in pairs if len(a)]
    return np.array([a for a, _ in kept]), np.array([b for _, b in kept])


def claims(
    definition: Definition, scale: Scale, errors: dict[str, Any], navigation: dict[str, Any]
) -> list[dict[str, Any]]:
    """The paper's claims (:data:`CLAIMS`) whose two rows the scale runs, one line per claim and
    measure (:data:`CLAIM_MEASURES`), tested on the trials both rows share; where both rows were
    trained under several seeds, over their training runs instead (:data:`OVER_RUNS`; ``tested_over``
    says which, ``pairs`` counts the trials or the runs), so a verdict there holds against the
    training-seed spread too. ``diff``: A's mean minus
    B's (%, or x 1e-2 for the error); ``p``: the test's two-sided p; ``p_holm``: Holm-adjusted over
    every test of the table; ``verdict``: ``supports`` (``p_holm`` < :data:`ALPHA` and ours differs in
    the direction the paper's numbers go, or where the paper gives none, A better), ``contradicts``
    (the other direction) or ``undecided``."""
    from odolab.core.stats import holm, mcnemar, paired_t

    lines, expected = [], []  # expected: the sign of diff the paper's numbers give (A better where it is silent)
    for a_row, b_row in CLAIMS:
        if a_row not in scale.rows or b_row not in scale.rows:
            continue
        over_runs = len(_training_runs(scale, a_row)) > 1 and len(_training_runs(scale, b_row)) > 1
        for measure, (_unit, higher_better, _test) in CLAIM_MEASURES.items():
            pick = _run_means if over_runs else _paired_values
            a, b = pick(scale, errors, navigation, (a_row, b_row), measure)
            scale_by = 100.0 if measure != "error" else 1.0
            line: dict[str, Any] = {
                "claim": f"{a_row} over {b_row}",
                "measure": measure,
                "paper_a": _paper_value(definition, a_row, measure),
                "paper_b": _paper_value(definition, b_row, measure),
                "ours_a": float(a.mean()) * scale_by if len(a) else math.nan,
                "ours_b": float(b.mean()) * scale_by if len(b) else math.nan,
                "tested_over": "training runs" if over_runs else "episodes",
                "pairs": len(a),
                "a_only": "",
                "b_only": "",
            }
            if measure == "success" and not over_runs:
                line["a_only"], line["b_only"], line["p"] = mcnemar(a, b) if len(a) else ("", "", math.nan)
                line["diff"] = line["ours_a"] - line["ours_b"]
            else:
                diff, line["p"] = paired_t((a - b) * scale_by)
                line["diff"] = diff
                if over_runs and len(a) and np.ptp(a - b) == 0:  # a few runs with no spread: no test
                    line["p"] = math.nan
            gap = line["paper_a"] - line["paper_b"]
            silent = not math.isfinite(gap) or gap == 0
            expected.append((1.0 if higher_better else -1.0) if silent else float(np.sign(gap)))
            lines.append(line)
    for line, adjusted, sign in zip(lines, holm([line["p"] for line in lines]), expected):
        line["p_holm"] = adjusted
        if not (math.isfinite(adjusted) and adjusted < ALPHA and line["diff"] != 0):
            line["verdict"] = "undecided"
        else:
            line["verdict"] = "supports" if np.sign(line["diff"]) == sign else "contradicts"
    return lines


def claims_table(lines: list[dict[str, Any]]) -> framework.Table:
    """The claims' lines as a report table, with what each test is and what the verdicts count."""
    from odolab.reporting.report import counted

    said = {v: sum(line["verdict"] == v for line in lines) for v in ("supports", "contradicts", "undecided")}
    tested = sum(math.isfinite(line["p"]) for line in lines)
    return framework.Table(
        name="claims",
        heading="The paper's claims, tested",
        intro=[
            "Each of the paper's pairwise claims (A over B) whose two rows this scale runs, per measure, on the "
            "trials both rows share (the same seeds and episodes): "
            + "; ".join(f"{m} ({unit}): {test}" for m, (unit, _, test) in CLAIM_MEASURES.items())
            + f". Where both rows were trained under several seeds (tested_over: training runs), every measure: {OVER_RUNS}, "
            "so the verdict holds against the training-seed spread, not only the episodes' (pairs then counts runs)"
            + f". diff is A's mean minus B's; p_holm is Holm's adjustment over the table's {counted(tested, 'test')} (lines without a p are not counted) "
            f"(family-wise error rate {ALPHA:g}). verdict: supports (p_holm < {ALPHA:g}, ours differs as the paper's "
            "numbers do), contradicts (the other way) or undecided (p_holm >= "
            f"{ALPHA:g}, or no shared trials). Here: {said['supports']} supports, {said['contradicts']} contradicts, "
            f"{said['undecided']} undecided."
        ],
        columns=CLAIM_COLUMNS,
        rows=lines,
    )


#: Each error component's unit, as the figure's axes name it.
UNITS = {"dx": "m", "dz": "m", "dyaw": "rad"}
#: The rows whose numbers the figure writes first (the reference, then DeepVO); the others follow
#: in order where a free place is left.
LABEL_FIRST = (REFERENCE_ROW, 0)
OURS_STYLE = {"color": "tab:blue", "marker": "o"}
PAPER_STYLE = {"color": "tab:orange", "marker": "s"}


def _paper_error(line: dict[str, Any], k: int) -> float:
    """The paper's ``k``-th error component of a line (x 1e-2), NaN where the paper gives none."""
    parts = line.get("paper_errors", ())
    return float(parts[k]) if len(parts) > k else float("nan")


def unplotted_paper_rows(lines: list[dict[str, Any]]) -> list[int]:
    """The rows with the paper's success but no per-component error of the paper's: not among the
    paper's points of the figure (ground truth, whose success is drawn as a line, among them)."""
    return [
        line["row"] for line in lines if math.isfinite(line["paper_S"]) and not math.isfinite(_paper_error(line, 0))
    ]


def figure_caption(lines: list[dict[str, Any]]) -> str:
    """The report's caption of :func:`draw`'s figure, naming the rows the paper gives no error for."""
    left_out = unplotted_paper_rows(lines)
    note = (
        f" The paper gives no per-component error for row{'s' if len(left_out) > 1 else ''} "
        f"{', '.join(map(str, left_out))}: left out of its points"
        + (
            " (ground truth's success is a dashed line)."
            if any(line["row"] in left_out and line["setting"] == "Ground truth" for line in lines)
            else "."
        )
        if left_out
        else ""
    )
    return (
        "Navigation success (%) against each component of the per-step error (x 1e-2: dx in m, dz in m, "
        "dyaw in rad), one panel per component: ours (circles; bars: success's 95 % interval) and the "
        "paper's Table 2 (squares) on the same axes; ground truth dashed, our action prior a star with "
        "dotted lines. Row numbers stand by the points where they fit without covering another label, "
        "point or bar (row 18 and DeepVO's row 0 first); every row's numbers are in the table." + note
    )


def figure(lines: list[dict[str, Any]]) -> Any:
    """Navigation success (%) against the per-step error, one panel per component (dx m, dz m,
    dyaw rad; x 1e-2): each trained row ours (circles, with the 95 % interval of success) and the
    paper's (squares, where the paper gives the component) on the same axes, whose x range runs
    from 0 past both; ground truth (zero error) as dashed lines, our action prior as a star and
    dotted lines; row numbers where they fit (:func:`_label_points`). The points' collections have
    the gids ``ours`` and ``paper``. Returns the figure, laid out and labelled."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    fig, axes = plt.subplots(1, len(COMPONENTS), figsize=(13.5, 7.0), sharey=True)
    trained = [line for line in lines if line["setting"] not in REFERENCES]
    prior = next((line for line in lines if line["setting"] == "Action prior"), None)
    truth = next((line for line in lines if line["setting"] == "Ground truth"), None)
    per_axis = []
    for k, (ax, c) in enumerate(zip(axes, COMPONENTS)):
        ours = [(line[c], line["S"], line["row"]) for line in trained if math.isfinite(line[c] + line["S"])]
        paper = [
            (_paper_error(line, k), line["paper_S"], line["row"])
            for line in trained
            if math.isfinite(_paper_error(line, k) + line["paper_S"])
        ]
        bars: list[tuple[float, float, float]] = []
        if ours:
            ranges = {line["row"]: line["S_range"] for line in trained}
            for x, y, n in ours:
                low, high = ranges[n]
                bars.append((x, min(y, low) if math.isfinite(low) else y, max(y, high) if math.isfinite(high) else y))
            ax.vlines([b[0] for b in bars], [b[1] for b in bars], [b[2] for b in bars], color="tab:blue", alpha=0.35)
            ax.scatter(*zip(*[(x, y) for x, y, _ in ours]), s=24, zorder=3, gid="ours", **OURS_STYLE)
        if paper:
            ax.scatter(*zip(*[(x, y) for x, y, _ in paper]), s=24, zorder=3, gid="paper", **PAPER_STYLE)
        guides = []
        if truth is not None:
            for y, color, style in ((truth["S"], "0.2", "--"), (truth["paper_S"], "tab:orange", "--")):
                if math.isfinite(y):
                    ax.axhline(y, color=color, linestyle=style, linewidth=1)
                    guides.append(("h", y))
        xs = [x for x, _, _ in ours + paper]
        if prior is not None and math.isfinite(prior[c] + prior["S"]):
            ax.axhline(prior["S"], color="0.45", linestyle=":", linewidth=1)
            ax.axvline(prior[c], color="0.45", linestyle=":", linewidth=1)
            ax.scatter([prior[c]], [prior["S"]], color="0.3", marker="*", s=150, zorder=4)
            guides += [("h", prior["S"]), ("v", prior[c])]
            xs.append(prior[c])
        ax.set_xlim(0.0, 1.08 * max(xs, default=1.0) or 1.0)
        ax.set_title(f"{c} ({UNITS[c]})")
        ax.set_xlabel(f"per-step error |{c}|, mean ({UNITS[c]} x 1e-2)")
        ax.grid(alpha=0.3)
        per_axis.append((ax, ours, paper, bars, guides, prior and (prior[c], prior["S"])))
    axes[0].set_ylabel("navigation success (%)")
    axes[0].set_ylim(-4, 104)
    handles = [
        Line2D(
            [], [], linestyle="", markersize=6, label="ours, trained rows (bar: 95 % interval of success)", **OURS_STYLE
        ),
        Line2D([], [], linestyle="", markersize=6, label="the paper's Table 2", **PAPER_STYLE),
    ]
    if prior is not None:
        handles.append(
            Line2D(
                [],
                [],
                color="0.3",
                marker="*",
                markersize=11,
                linestyle=":",
                label=f"action prior, ours (row {prior['row']}): {prior['S']:.0f} %",
            )
        )
    if truth is not None:
        handles += [
            Line2D([], [], color=color, linestyle="--", label=f"ground truth (row {truth['row']}), {who}: {y:.0f} %")
            for y, color, who in ((truth["S"], "0.2", "ours"), (truth["paper_S"], "tab:orange", "the paper's"))
            if math.isfinite(y)
        ]
    fig.legend(handles=handles, loc="lower center", ncol=3, fontsize=9, frameon=False)
    fig.suptitle(
        "Navigation success against each component of the per-step VO error, per row of Table 2 "
        "(numbers: row; ours blue, the paper's orange)",
        fontsize=11,
    )
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    for ax, ours, paper, bars, guides, star in per_axis:
        _label_points(ax, ours, paper, bars, guides, [star] if star else [])
    return fig


def draw(lines: list[dict[str, Any]], path: Path) -> None:
    """:func:`figure`, saved to ``path``."""
    fig = figure(lines)
    import matplotlib.pyplot as plt

    from odolab.io.atomic import save_figure_atomic

    save_figure_atomic(fig, path)
    plt.close(fig)


def _segment_meets_box(box: Any, a: np.ndarray, b: np.ndarray) -> bool:
    """Whether the segment from ``a`` to ``b`` (pixels) meets ``box`` (Liang-Barsky clipping)."""
    lo, hi = 0.0, 1.0
    d = b - a
    for p, q in ((-d[0], a[0] - box.x0), (d[0], box.x1 - a[0]), (-d[1], a[1] - box.y0), (d[1], box.y1 - a[1])):
        if p == 0:
            if q < 0:
                return False
        elif p < 0:
            lo = max(lo, q / p)
        else:
            hi = min(hi, q / p)
        if lo > hi:
            return False
    return True


def _segments_cross(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> bool:
    """Whether the segments ``a``-``b`` and ``c``-``d`` (pixels) cross (touching ends do not count)."""

    def side(p: np.ndarray, q: np.ndarray, r: np.ndarray) -> float:
        return float((q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]))

    return side(a, b, c) * side(a, b, d) < 0 and side(c, d, a) * side(c, d, b) < 0


def _label_points(
    ax: Any,
    ours: Sequence[tuple[float, float, int]],
    paper: Sequence[tuple[float, float, int]],
    bars: Sequence[tuple[float, float, float]] = (),
    guides: Sequence[tuple[str, float]] = (),
    stars: Sequence[tuple[float, float]] = (),
) -> int:
    """Write the row number by each point (ours in blue, the paper's in orange) where it covers no
    other label, point, leader line, interval bar (``bars``: x, low, high in data units), guide
    line (``guides``: ("h", y) or ("v", x)) or star (``stars``): the first free spot on rings of
    growing radius around the point, nearer its own point than any other (on the nearest rings) or
    joined to it by a thin line crossing no bar or other line (beyond them). A point with no free
    spot goes unlabelled. Rows of :data:`LABEL_FIRST` come first, then the others in
    order, ours before the paper's. Call after the layout is final (positions are in pixels).
    Returns how many labels were written."""
    from matplotlib.text import Text
    from matplotlib.transforms import Bbox

    renderer = ax.figure.canvas.get_renderer()
    to_px = ax.transData.transform
    frame = ax.get_window_extent(renderer)
    points = [(x, y, n, "tab:blue") for x, y, n in ours] + [(x, y, n, "tab:orange") for x, y, n in paper]
    marks = [to_px((x, y)) for x, y, _, _ in points]
    big = [to_px(s) for s in stars]
    segments = [(to_px((x, low)), to_px((x, high))) for x, low, high in bars]  # bars, then leader lines
    lines = []  # the guide lines: no label on them; a leader line may cross one
    for kind, v in guides:
        ends = (
            ((frame.x0, to_px((0, v))[1]), (frame.x1, to_px((0, v))[1]))
            if kind == "h"
            else ((to_px((v, 0))[0], frame.y0), (to_px((v, 0))[0], frame.y1))
        )
        lines.append(tuple(np.array(e) for e in ends))
    legend = ax.get_legend()
    taken = [legend.get_window_extent(renderer)] if legend is not None else []
    first = {n: k for k, n in enumerate(LABEL_FIRST)}
    order = sorted(
        range(len(points)),
        key=lambda i: (first.get(points[i][2], len(first)), points[i][2], points[i][3] != "tab:blue"),
    )
    rings = [(r, a) for r in (5, 14, 24, 36, 50, 66) for a in range(0, 360, 30)]
    written = 0
    for i in order:
        x, y, number, color = points[i]
        mark = marks[i]
        for k, (radius, angle) in enumerate(rings):
            dx, dy = radius * math.cos(math.radians(angle)), radius * math.sin(math.radians(angle))
            leader = k >= 12
            note = ax.annotate(
                str(number),
                (x, y),
                textcoords="offset points",
                xytext=(dx, dy),
                ha="left" if dx >= 0 else "right",
                va="bottom" if dy >= 0 else "top",
                fontsize=8.5,
                color=color,
                gid="row-label",
                arrowprops={"arrowstyle": "-", "color": color, "lw": 0.8, "shrinkA": 1, "shrinkB": 3}
                if leader
                else None,
            )
            note.update_positions(renderer)
            text = Text.get_window_extent(note, renderer)  # the text alone, not its line
            box = Bbox.from_extents(text.x0 - 3, text.y0 - 2, text.x1 + 3, text.y1 + 2)
            anchor = np.array([(text.x0 + text.x1) / 2, (text.y0 + text.y1) / 2])
            near = Bbox.from_extents(box.x0 - 3, box.y0 - 3, box.x1 + 3, box.y1 + 3)
            free = (
                frame.contains(box.x0, box.y0)
                and frame.contains(box.x1, box.y1)
                and not any(box.overlaps(b) for b in taken)
                and not any(near.contains(*p) for p in marks)
                and not any(Bbox.from_extents(*(s - 9), *(s + 9)).overlaps(box) for s in big)
                and not any(_segment_meets_box(box, a, b) for a, b in (*segments, *lines))
                and not (leader and any(_segment_meets_box(b, mark, anchor) for b in taken))
                and not (leader and any(_segments_cross(mark, anchor, a, b) for a, b in segments))
                and (
                    leader
                    or all(np.hypot(*(anchor - p)) > np.hypot(*(anchor - mark)) for p in marks + big if p is not mark)
                )
                and not (
                    leader
                    and any(
                        _segment_meets_box(Bbox.from_extents(*(p - 2.5), *(p + 2.5)), mark, anchor)
                        for j, p in enumerate(marks)
                        if j != i
                    )
                )
            )
            if free:
                taken.append(box)
                if leader:
                    segments.append((mark, anchor))
                written += 1
                break
            note.remove()
    return written


# -------------------------------------------------------------------------------------------- main


def check_folders(out: Path) -> None:
    """Refuse an ``out`` whose model, work, training or data folder is a link or a file."""
    from odolab.cli import UsageError
    from odolab.io.owned import UnsafeOutputError, check_owned_folder

    for name in FOLDERS:
        try:
            check_owned_folder(out, name)
        except UnsafeOutputError as exc:
            raise UsageError(f"--out {out}: {exc}") from None


def check_gpus(scale: Scale, name: str, *, serial: bool, address: str | None, redraw: bool) -> None:
    """Before anything is made: ``UsageError`` when the scale asks Ray for GPUs per training unit
    and the local instance it would start has none (a cluster's are counted when it connects)."""
    from odolab.cli import UsageError

    if scale.train_gpus > 0 and not serial and address is None and not redraw and not os.environ.get("RAY_ADDRESS"):
        import torch

        have = torch.cuda.device_count()
        if have < scale.train_gpus:
            raise UsageError(
                f"--scale {name} asks Ray for {scale.train_gpus:g} GPU per training unit (train_gpus in "
                f"{DEFINITION.name}) and this machine has {have}; give --ray-address of a cluster with "
                "GPUs, or --serial to train in this process"
            )


def _only_rows(
    text: str | None, scale: Scale, name: str, definition: Definition
) -> Callable[[framework.Unit], bool] | None:
    """``--rows N,N,...`` as a choice of units (a listed row's errors and navigation, and the model it
    runs: row 5's is row 4's), or None for every unit; :class:`UsageError` for a row the scale does
    not run."""
    from odolab.cli import UsageError

    if text is None:
        return None
    parts = [t.strip() for t in text.split(",")]
    if not all(re.fullmatch(r"[0-9]{1,9}", t) for t in parts):
        raise UsageError(f"--rows: expected row numbers separated by commas, got {text!r}")
    chosen = {int(t) for t in parts}
    unknown = sorted(chosen - set(scale.rows))
    if unknown:
        raise UsageError(
            f"--rows: row {unknown[0]} is not a row of --scale {name} (its rows: {', '.join(map(str, scale.rows))})"
        )
    models = {model_row(definition.rows[r]) for r in chosen}  # the rows whose models the chosen rows run
    # a training unit's key holds its recipe and names the model's row; an evaluation's, the row evaluated
    return lambda unit: unit.key["row"] in (models if "recipe" in unit.key else chosen)


def make_data(recipes: list[TrainConfig | DeepVOTraining], execution: Execution) -> None:
    """Every data set the recipes train on, made here (once each) before the training units start,
    so that no two units make the same folder at once; the caller passes the recipes of the models
    still to train."""
    from odolab.sim.training_data import make_training_data

    made = set()
    for cfg in recipes:
        for data in (cfg.train_data, cfg.val_data):
            folder = cfg.data_folder(data)
            if folder not in made:
                make_training_data(data, folder, execution=execution)
                made.add(folder)


def study_config() -> framework.StudyConfig:
    """The study part of ``studies/ablations.toml`` (:func:`load_definition`; ``ValueError`` names
    the file and field)."""
    return load_definition().study


def run(args) -> int:
    """The study as its command line (:mod:`odolab.cli.study`) asks; 0 when its report is written."""
    from odolab.cli import UsageError, execution_of
    from odolab.config import ConfigError
    from odolab.reporting.report import counted

    try:
        definition = load_definition()
    except ConfigError as exc:
        raise UsageError(str(exc)) from None
    scale = definition.scales[args.scale]
    if args.rows is not None and args.redraw:
        raise UsageError("--rows chooses units to compute; --redraw computes none: give one of them")
    only = _only_rows(args.rows, scale, args.scale, definition)
    out = args.out or default_out(args.scale)
    check_gpus(scale, args.scale, serial=args.serial, address=args.ray_address, redraw=args.redraw)
    framework.check_cache(args)
    _held = framework.check_options(args, out, definition.study)  # this run's hold on out, kept until main returns
    check_folders(out)
    out = out.resolve()  # the units run elsewhere (Ray workers): every path they get is absolute
    try:
        wanted = sorted({n for r in scale.rows if (n := model_row(definition.rows[r])) is not None})
        root = data_root(scale, out)
        recipes = {(n, None): recipe(definition, scale, n, root) for n in wanted}
        recipes |= {
            (n, k): recipe(definition, scale, n, root, k) for n in scale.train_seed_rows for k in scale.train_seeds
        }
        for n, k in recipes:
            path = out / model_file(n, k)
            if path.is_dir() and not path.is_symlink():
                raise UsageError(f"--out {out}: {path}: expected row {n}'s model file or nothing, found a folder")
        for r in scale.rows:  # option values as the odometer takes them, switches as trained: before any work
            check_option_values(definition, r)
            if definition.rows[r].switches is not None:
                check_switches(definition, r, recipes[(model_row(definition.rows[r]), None)])
    except ConfigError as exc:
        raise UsageError(str(exc)) from None
    execution = execution_of(args)
    store = framework.ResultStore(out / "results")
    training = train_units(definition, recipes)
    # the model files of the rows this run computes must be there; the others' saved results are read
    # as they are (a checkout holding the results and not every model still reports every row)
    computed = {model_file(u.key["row"], u.key.get("train_seed")) for u in training if only is None or only(u)}

    def trained_valid(value: Any) -> bool:
        mine = isinstance(value, dict) and value.get("model") in computed
        return valid_model(value, out=out, check_file=mine and not args.redraw)

    if not args.redraw:  # the data of the models still to train (a resumed study may need none)
        to_train = [u for u in framework.unsaved(training, store, trained_valid) if only is None or only(u)]
        check_states(to_train, out)
        say_retrained(to_train, store)
        saved = ((u, store.get(u)) for u in training)  # models of earlier runs: their states go first
        drop_finished_states(training, {u.label: v.get("value") for u, v in saved if isinstance(v, dict)}, out)
        make_data([recipes[(u.key["row"], u.key.get("train_seed"))] for u in to_train], execution)

    def evaluations(
        before: Sequence[framework.Outcome],
    ) -> tuple[list[framework.Unit], list[framework.Unit], list[str]]:
        return evaluation_units(definition, scale, before[0].results)

    def states_done(unit: framework.Unit, value: Any) -> None:  # once its result is saved: a stopped run keeps them
        drop_finished_states([unit], {unit.label: value}, out)

    # one pipeline: a model's errors and navigation are queued once it is trained, behind the models
    # still to train, so a core that the last, longest training leaves idle evaluates meanwhile
    try:
        trained, errors, navigation = framework.run_phases(
            [
                framework.Phase(
                    functools.partial(
                        train_row, out=out, recipes=recipes, device=scale.device, threads=scale.train_threads
                    ),
                    lambda _before: training,
                    trained_valid,
                    scale.train_gpus,
                    None if args.redraw else states_done,
                ),
                framework.Phase(
                    functools.partial(step_errors, out=out, cache=getattr(args, "cache", None)),
                    lambda b: evaluations(b)[0],
                    valid_errors,
                ),
                framework.Phase(
                    functools.partial(navigate_episode, out=out), lambda b: evaluations(b)[1], valid_navigation
                ),
            ],
            store,
            redraw=args.redraw,
            execution=execution,
            only=only,
        )
    except BrokenOdometer as exc:  # what is saved stays; a rerun once the odometer runs goes on from it
        raise UsageError(str(exc)) from None
    untrained = evaluations([trained])[2]
    outcomes = (trained, errors, navigation)
    if not any(o.results for o in outcomes):  # only --redraw computes nothing
        raise UsageError(
            f"--redraw: no saved results in {out / 'results'} for --scale {args.scale}; run without --redraw"
        )
    lines = table(definition, scale, trained.results, errors.results, navigation.results)
    missing = [*untrained, *(label for o in outcomes for label in o.missing)]
    report = framework.Report(
        title=definition.study.title,
        intro=[
            " ".join(__doc__.split("\n\n")[2].split()).replace("``", ""),
            f"Scale {args.scale}: rows {', '.join(map(str, scale.rows))}; per-step error on "
            f"{counted(scale.episodes, 'test episode')} of at most {counted(scale.max_steps, 'step')} "
            f"{_for_seeds(scale.seeds)}; navigation on {counted(scale.nav_episodes, 'test episode')} of at most "
            f"{counted(scale.nav_max_steps, 'step')} {_for_seeds(scale.nav_seeds)}. "
            "S, SPL, SoftSPL in %, d_G in m, "
            "errors x 1e-2 (mean and standard deviation over the seeds), fps in steps/s of the odometer alone; "
            "*_ci: 95 % intervals (Wilson's for S, Student's t for the others, kept within 0-100 % and d_G >= 0). S_vs_18 and error_vs_18 say "
            "whether the row lies on the same side of row 18 as in the paper, '(overlap)' where our intervals "
            "of the two rows overlap (not settled at this sample size)." + framework.missing_note(missing),
            *(f"Row {r}: {definition.rows[r].note}" for r in scale.rows if definition.rows[r].note),
        ],
        columns=COLUMNS,
        rows=lines,
        figures={"success-vs-error.png": (figure_caption(lines), lambda p: draw(lines, p))},
        findings=[*findings(lines), *floor_findings(lines), *claim_findings(lines)],
        tables=[claims_table(claims(definition, scale, errors.results, navigation.results))],
        command=args.command,
        machine=framework.machines(outcomes),
        cpu_hours=sum(o.seconds for o in outcomes) / 3600,
    )
    framework.write_report(report, out, owner=f"study {NAME}")
    print(framework.table_md(["row", "setting", "S", "paper_S", "SPL", "d_G", "dx", "dz", "dyaw", "S_vs_18"], lines))
    computed = sum(len(o.computed) for o in outcomes)
    print(
        f"{counted(computed, 'unit')} computed ({', '.join(f'{len(o.computed)} {n}' for o, n in zip(outcomes, PHASES))})"
    )
    print(f"{counted(len(lines), 'row')} -> {out}; open {out / 'index.html'}")
    framework.say_missing(missing)
    return 0


if __name__ == "__main__":  # python -m studies.ablations: the command line is odolab.cli.study's
    import importlib

    study = importlib.import_module("odolab.cli.study")
    study.exit_process(study.command("ablations"))
