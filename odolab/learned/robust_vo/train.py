"""Train the robust VO from a TOML recipe, stage by stage, resumably; export the shipped checkpoint.

    python -m odolab.learned.robust_vo.train --config studies/robust_vo/shipped.toml --hours 1.8

One command does everything: it makes the train and val data when missing (Ray tasks), then runs
each stage of the recipe in order (each stage's networks start from the last stage that trained
them), saving after every epoch under ``--work``; it writes validation curves (CSV, PNG) and a
``training.json`` under ``--reports`` after every epoch, and exports the networks to ``--export``
once every stage is finished. Stopped at any moment (or by ``--hours``), the same command resumes.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from odolab.api import Action
from odolab.learned.robust_vo.batches import Batch, Pairs, Samples, network_inputs, read_pairs, stage_samples
from odolab.learned.robust_vo.checkpoint import apply_start, init_stages, load_start, resized_start, save_model
from odolab.learned.robust_vo.config import ModelConfig, StageConfig, TrainConfig, load_train_config
from odolab.learned.robust_vo.model import build_networks, predict
from odolab.learned.robust_vo.motion import geoinv_loss
from odolab.learned.training import EpochLoop, Execution, TrainingData, make_training_data, require_finite
from odolab.learned.training.compute import Compute
from odolab.learned.training.distributed import Team
from odolab.learned.training.epochs import EpochTracker
from odolab.learned.training.trainer import Trainer
from odolab.learned.training.validation import error_rows, write_report


def open_data(cfg: TrainConfig, *, execution: Execution = Execution()) -> tuple[TrainingData, TrainingData]:
    """The recipe's train and val data, made first where missing."""
    out = []
    for data in (cfg.train_data, cfg.val_data):
        folder = cfg.data_folder(data)
        make_training_data(data, folder, execution=execution)
        out.append(TrainingData(folder))
        out[-1].verify(execution.progress)
    return out[0], out[1]


def stage_networks(cfg: TrainConfig, stage: StageConfig) -> list[str]:
    """Names of the networks a stage trains."""
    return list(dict.fromkeys(cfg.model.model_for(a) for a in stage.action_set))


def _mse(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    return (pred.float() - target).pow(2).sum(dim=1).mean()


class StepBatches:
    """What one training step reads, made in a loader worker (or the training process): the batch of
    ``samples`` and, for GeoInv, the same pairs swapped. For a CPU ``device`` the batches are made
    whole there (on the CPU); for a GPU only the frames are read there (:class:`Pairs`) and
    :meth:`finish` makes the network inputs on the GPU, which copies a ninth of the bytes and leaves
    the warp and psi to the GPU (``inputs_in_loader`` overrides the choice). Picklable (the data's
    maps reopen in each worker)."""

    def __init__(
        self,
        data: TrainingData,
        cfg: ModelConfig,
        geoinv: bool,
        device: torch.device = torch.device("cpu"),
        inputs_in_loader: bool | None = None,
    ) -> None:
        self.data, self.cfg, self.geoinv, self.device = data, cfg, geoinv, device
        self.inputs_in_loader = device.type == "cpu" if inputs_in_loader is None else inputs_in_loader

    def __call__(self, samples: Samples) -> tuple[Batch | Pairs, Batch | Pairs | None]:
        made = [read_pairs(self.data, samples, swap_all=s) for s in ((False, True) if self.geoinv else (False,))]
        if self.inputs_in_loader:  # on the CPU: the step moves them to its device
            made = [network_inputs(p, self.data.intrinsics, self.cfg, torch.device("cpu")) for p in made]
        return made[0], made[1] if self.geoinv else None

    def finish(self, made: tuple[Batch | Pairs, Batch | Pairs | None]) -> tuple[Batch, Batch | None]:
        """The batches of one step on the device, from what :meth:`__call__` made."""
        return tuple(  # type: ignore[return-value]
            network_inputs(m, self.data.intrinsics, self.cfg, self.device) if isinstance(m, Pairs) else m for m in made
        )

    def advise(self, samples: Samples) -> None:
        """Start reading the frames of ``samples`` (see :meth:`TrainingData.prefetch`)."""
        f = self.data.pairs[samples.pair]
        self.data.prefetch(np.concatenate([f, f + 1]))


class StageRunner:
    """One stage: its samples, optimiser, epoch function and validation."""

    def __init__(
        self,
        cfg: TrainConfig,
        stage: StageConfig,
        train: TrainingData,
        val: TrainingData,
        nets: torch.nn.ModuleDict,
        compute: Compute,
        progress: bool = True,
        team: Team = Team(),
    ) -> None:
        self.cfg, self.stage, self.train, self.val, self.nets, self.team = cfg, stage, train, val, nets, team
        self.compute, self.device = compute, compute.device
        self.names = stage_networks(cfg, stage)
        self.samples = stage_samples(train, stage)
        if not len(self.samples):
            raise ValueError(f"stage {stage.name!r}: no training pairs for {', '.join(stage.actions)}")
        self.params = [p for n in self.names for p in nets[n].parameters()]
        self.optimizer = torch.optim.Adam(self.params, lr=stage.lr)
        self.progress = progress
        rng = np.random.default_rng(cfg.seed)
        chosen = val.select(stage.action_set)
        if cfg.val_pairs and len(chosen) > cfg.val_pairs:
            chosen = np.sort(rng.choice(chosen, cfg.val_pairs, replace=False))
        self.val_pairs = chosen

    def init_bias(self) -> None:
        """Start each network's output at the mean target of its training pairs (a fresh network then
        begins at the action prior instead of at zero)."""
        model = self.cfg.model
        for name in self.names:
            acts = [a for a in self.stage.action_set if model.model_for(a) == name]
            # the targets as the network sees them: a mirrored action's are mirrored
            seen = [
                self.train.pair_planar[self.train.select([a])] * ((-1.0, 1.0, -1.0) if model.mirrored(a) else 1.0)
                for a in acts
            ]
            mean = np.concatenate(seen).mean(axis=0)
            with torch.no_grad():
                self.nets[name].head[-1].bias.copy_(torch.from_numpy(mean).to(torch.float32))

    def train_epoch(self, epoch: int, rng: np.random.Generator, tracker: EpochTracker) -> dict:
        """One epoch over the stage's samples in a random order, from batch ``tracker.start`` on; in a
        team, each worker takes its share of every batch (a last batch smaller than the team is dropped)."""
        stage, team = self.stage, self.team
        order = rng.permutation(len(self.samples))
        if stage.pairs_per_epoch:
            order = order[: stage.pairs_per_epoch]
        batches = [
            b
            for b in (np.sort(order[k : k + stage.batch]) for k in range(0, len(order), stage.batch))
            if len(b) >= team.size
        ][tracker.start :]
        parts = [self.samples.take(team.share(b)) for b in batches]
        bar = tqdm(
            total=len(order),
            initial=tracker.samples,
            desc=f"{stage.name} epoch {epoch}",
            unit="pair",
            disable=not (self.progress and team.leader),
            leave=False,
        )
        c = self.compute
        steps = StepBatches(self.train, self.cfg.model, stage.geoinv, self.device)
        for made, whole in zip(c.batches(parts, steps), batches):
            batch, other = steps.finish(made)
            with c.autocast():
                pred = predict(self.nets, self.cfg.model, c.inputs(batch.x), batch.action)
            loss = _mse(pred, batch.target.to(self.device))
            if other is not None:
                with c.autocast():
                    pred_ba = predict(self.nets, self.cfg.model, c.inputs(other.x), other.action)
                loss = loss + _mse(pred_ba, other.target.to(self.device)) + geoinv_loss(pred.float(), pred_ba.float())
            require_finite(loss, epoch)
            self.optimizer.zero_grad(set_to_none=True)
            loss.backward()
            team.average_gradients(self.params, len(batch.action))
            self.optimizer.step()
            team.average_buffers(self.nets[n] for n in self.names)
            bar.update(len(whole))
            tracker.add(loss.item(), len(whole))  # pairs of the whole batch (every worker's share)
        bar.close()
        return {"stage": stage.name}

    def validate(self, epoch: int) -> list[dict]:
        """Mean absolute error per action and component on the val pairs, beside the action prior's
        (in fp32, as the odometer runs, whatever precision trains)."""
        preds, targets, actions = [], [], []
        parts = [
            Samples(idx, np.zeros(len(idx), bool), np.zeros(len(idx), bool))
            for idx in np.array_split(self.val_pairs, max(1, -(-len(self.val_pairs) // 64)))
        ]
        c = self.compute
        steps = StepBatches(self.val, self.cfg.model, False, self.device)
        for made in self.compute.batches(parts, steps):
            batch, _ = steps.finish(made)
            preds.append(predict(self.nets, self.cfg.model, c.inputs(batch.x), batch.action).cpu().numpy())
            targets.append(batch.target.cpu().numpy())
            actions.append(batch.action)
        if not preds:
            return []
        return error_rows(
            np.concatenate(preds),
            np.concatenate(targets).astype(np.float64),
            np.concatenate(actions),
            stage=self.stage.name,
        )


def _identity(cfg: TrainConfig, stage: StageConfig, init_sha256: str = "") -> dict:
    """What a saved stage state must match to be resumed: everything but this stage's number of
    epochs, the earlier stages included (a stage trained on top of other weights is another run);
    a stage without turns leaves out ``mirror_turns``, which only decides the turn networks; a start
    from ``init`` is identified by its file's digest (``init_sha256``)."""
    doc = json.loads(json.dumps(dataclasses.asdict(cfg)))
    if not {Action.TURN_LEFT, Action.TURN_RIGHT} & set(stage.action_set):
        del doc["model"]["mirror_turns"]  # which network answers right turns cannot change this stage
    k = cfg.stages.index(stage)
    stage_doc = {key: v for key, v in doc["stages"][k].items() if key != "epochs"}
    out = {
        "model": doc["model"],
        "stage": stage_doc,
        "before": doc["stages"][:k],
        "train_data": doc["train_data"],
        "val_data": doc["val_data"],
        "seed": cfg.seed,
        "val_pairs": cfg.val_pairs,
    }
    if init_sha256:
        out["init_sha256"] = init_sha256
    return out


def _write_reports(reports: Path, curves_rows: list[dict], status: dict, final: bool = True) -> None:
    offsets, total = {}, 0  # "epoch" counts within a stage; "epochs" counts over the stages in order
    for row in curves_rows:
        if row["stage"] not in offsets:
            offsets[row["stage"]] = total
        total = max(total, offsets[row["stage"]] + row["epoch"])
    rows = [{**r, "epochs": offsets[r["stage"]] + r["epoch"]} for r in curves_rows]
    spans = {}
    for r in rows:
        spans.setdefault(r["stage"], set()).add(r["epochs"])
    said = ", ".join(f"{name}: {min(e)}" + (f"-{max(e)}" if max(e) > min(e) else "") for name, e in spans.items())
    write_report(
        reports,
        rows,
        status,
        f"Robust VO: validation error after each epoch (epochs of {said})",
        x="epochs",
        final=final,
    )


def run(
    cfg: TrainConfig,
    *,
    work: Path,
    reports: Path,
    export: Path,
    device: torch.device,
    hours: float | None,
    execution: Execution = Execution(),
    command: str = "",
    workers: int = 1,
    gpus_per_worker: float = 0.0,
) -> bool:
    """Run (or resume) every stage; export when all are done. Returns True when finished. With
    ``workers`` > 1, data-parallel on Ray Train (:mod:`odolab.learned.training.distributed`); the data are
    made first, here. ``execution``: where the data are made (and the workers run), and whether
    with progress bars."""
    if cfg.init:
        load_start(cfg.init, cfg, export)  # checked before any data is made
    train, val = open_data(cfg, execution=execution)
    job = {
        "cfg": cfg,
        "work": work,
        "reports": reports,
        "export": export,
        "hours": hours,
        "progress": execution.progress,
        "command": command,
    }
    if workers == 1:
        return bool(train_stages({**job, "train": train, "val": val, "device": device, "team": Team()})["finished"])
    from odolab.learned.training.distributed import run_on_ray

    return run_on_ray(
        _team_member,
        job,
        workers=workers,
        work=work,
        export=export,
        ray_address=execution.ray_address,
        gpus_per_worker=gpus_per_worker,
    )


def _team_member(job: dict) -> dict:
    """One Ray Train worker: opens the data the driver made and trains its share."""
    from odolab.learned.training import pick_device

    cfg = job["cfg"]
    train, val = (TrainingData(cfg.data_folder(d)) for d in (cfg.train_data, cfg.val_data))
    device = pick_device("cuda" if torch.cuda.is_available() else "cpu")
    if device.type == "cuda":
        import ray.train.torch

        device = ray.train.torch.get_device()
    return train_stages({**job, "train": train, "val": val, "device": device})


def train_stages(job: dict) -> dict:
    """Every stage of ``job["cfg"]`` on opened data, as one worker of ``job["team"]``; returns
    ``{"finished": bool}``."""
    cfg, work, reports, export, team = job["cfg"], job["work"], job["reports"], job["export"], job["team"]
    train, val, progress = job["train"], job["val"], job["progress"]
    deadline = time.monotonic() + job["hours"] * 3600 if job["hours"] else None
    start, init_sha256 = load_start(cfg.init, cfg, export) if cfg.init else (None, "")
    compute = cfg.compute.resolve(job["device"])
    torch.manual_seed(cfg.seed)
    nets = build_networks(cfg.model)
    last_trained: dict[str, str] = {}  # network -> last stage that trained it
    if start is not None:
        apply_start(nets, start)
        if not resized_start(start):  # a fresh head gets the mean motion as its bias, as a fresh network
            last_trained = {name: "init" for name in nets}
    compute.prepare(nets)
    all_rows: list[dict] = []
    status = {
        "command": job["command"],
        "compute": {**compute.describe(), "workers": team.size},
        "train_pairs": train.counts(),
        "val_pairs": val.counts(),
        "stages": {},
    }
    if cfg.init:  # where the networks started: the scaling study counts the start's own training
        status["init"] = {"path": cfg.init, "sha256": init_sha256, "stages": init_stages(cfg.init)}
    finished = True
    previous: EpochLoop | None = None  # the stage before, compacted once this one has started
    for stage in cfg.stages:
        runner = StageRunner(cfg, stage, train, val, nets, compute, progress, team)
        loop = EpochLoop(
            work / f"{stage.name}.pt",
            {n: nets[n] for n in runner.names},
            runner.optimizer,
            stage.epochs,
            cfg.seed,
            _identity(cfg, stage, init_sha256),
            team=team,
        )
        loop.resume()
        if not loop.started:
            fresh = [n for n in runner.names if n not in last_trained]
            if fresh:
                runner.init_bias()
        if finished:

            def after(
                loop_: EpochLoop, stage: StageConfig = stage, rows: list[dict] = all_rows, final: bool = False
            ) -> None:
                _write_reports(
                    reports,
                    rows + loop_.curves.rows,
                    {**status, "stages": {**status["stages"], stage.name: _stage_status(loop_)}},
                    final=final,
                )

            try:
                finished = loop.run(runner.train_epoch, runner.validate, deadline=deadline, after_epoch=after)
            except BaseException:  # interrupted: the figure shows every finished epoch before it goes
                if team.leader:
                    after(loop, final=True)
                raise
        status["stages"][stage.name] = _stage_status(loop)
        if previous is not None and loop.started:
            previous.compact()
        previous = loop
        all_rows += loop.curves.rows
        for n in runner.names:
            last_trained[n] = stage.name
        if not finished:
            break
    if team.leader:
        _write_reports(reports, all_rows, status)
        if finished:
            save_model(export, cfg, nets, status)
    if finished and previous is not None:  # the model is exported: no step reads the last stage's moments
        previous.compact()
    return {"finished": finished}


def _stage_status(loop: EpochLoop) -> dict:
    return {
        "epochs_done": loop.epoch,
        "epochs": loop.epochs,
        "hours": round(loop.seconds / 3600, 3),
        "pairs_seen": int(sum(r.get("pairs", 0) for r in loop.curves.rows if r.get("split") == "train")),
    }


#: What the training command line (odolab.cli.train) needs of this trainer.
TRAINER = Trainer(
    family="robust-vo",
    description=__doc__.split("\n")[0],
    load_config=load_train_config,
    run=run,
    check_start=lambda cfg, export: load_start(cfg.init, cfg, export),
    set_example="seed=1 --set stages.forward.lr=1e-4 --set model.dropout=0.1",
)


if __name__ == "__main__":  # python -m odolab.learned.robust_vo.train: the command line is odolab.cli.train's
    import importlib

    train = importlib.import_module("odolab.cli.train")
    train.exit_process(train.command("robust-vo"))
