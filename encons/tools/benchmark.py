"""Benchmark runner: the runs of a profile (conf/profile/*.yaml), trained one by one, then the report.

    python -m encons.benchmark [profile=smoke|quick|zhong|finzi|lim_kasim|pixels|santos|xiao|control]
        [seeds=[0,1]] [out=DIR]
        ['train=["trainer.max_epochs=50"]']   (quoted: Hydra's grammar wants '=' inside a list quoted)

A profile lists its runs as a grid (``systems`` × ``models``), as explicit ``runs`` (a label and
its train overrides, e.g. a model with a regulariser) and as data-efficiency runs (``n_train`` on
each ``n_train_system``, models by name or as ``{label, overrides}``, ``per_n_train`` overrides);
each is trained for every seed of ``seeds``, the seeds of one cell as one ensemble in one process
(``encons.training.ensemble``: each member the run of its seed, with its own ``runs/<id>/``), on datasets cached under
``paths.cache_dir`` (one per system and data config, shared by every model and seed). A finished
run leaves ``runs/<id>/result.json``; a rerun skips it, so an interrupted benchmark resumes where it
stopped. Progress (stdout, the stream a run logs to) prints ``benchmark run k of n (id), elapsed, ETA``.
``models=all`` / ``systems=all`` take every option of ``conf/model`` / ``conf/system``. The report
(``encons.tools.report``) is written to ``out`` at the end and can be rebuilt alone with
``python -m encons.report OUT``.
"""

from __future__ import annotations

import json
import shutil
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from omegaconf import DictConfig, OmegaConf

from encons.infra import threads
from encons.infra.errors import ConfigError, EnconsError, Interrupted
from encons.infra.io import write_json, write_yaml
from encons.infra.paths import config_dir
from encons.tools.report import recorded, recorded_override

if TYPE_CHECKING:
    from encons.training.results import Run


@dataclass
class PlannedRun:
    """One training run of a benchmark: ``label`` is the model column of the tables."""

    system: str
    label: str
    seed: int
    overrides: list[str]
    n_train: int | None = None
    paper: dict = field(default_factory=dict)

    @property
    def cell(self) -> str:
        """The (system, model, size) cell: the runs of its seeds train as one ensemble
        (``encons.training.ensemble``)."""
        size = f"-n{self.n_train}" if self.n_train is not None else ""
        return f"{self.system}-{self.label}{size}".replace("/", "_").replace("'", "p")

    @property
    def id(self) -> str:
        return f"{self.cell}-seed{self.seed}"


def plain(cfg: DictConfig) -> dict:
    """The benchmark config without Hydra's own node, resolved."""
    return {
        k: OmegaConf.to_container(cfg[k], resolve=True) if OmegaConf.is_config(cfg[k]) else cfg[k]
        for k in cfg
        if k != "hydra"
    }


def recorded_config(config: dict, out: Path) -> dict:
    """``benchmark.yaml``'s content: the config with its folders (``out``, ``cache_dir``) and the absolute paths its
    ``common`` and ``train`` overrides give (``train=["data.path=/scratch/offset.npz"]``: every run's data file) as a
    report records them (``encons.tools.report.recorded``, ``recorded_override``), never the machine's absolute path."""
    return {
        **config,
        **{k: recorded(config[k], out) for k in ("out", "cache_dir") if config.get(k)},
        **{k: [recorded_override(o, out) for o in config[k]] for k in ("common", "train") if config.get(k)},
    }


def expand(cfg: DictConfig) -> list[PlannedRun]:
    """Every run of the profile: grid, listed runs and data-efficiency runs, times seeds."""
    from encons.training.build import catalogue

    c = plain(cfg)
    check_keys(c)
    # the command's hydra.searchpath (a user's conf/ with models and systems of their own) reaches every run
    folders = list(cfg.hydra.searchpath) if "hydra" in cfg and cfg.hydra.get("searchpath") else []
    searched = ["hydra.searchpath=[" + ",".join(f"'{f}'" for f in folders) + "]"] if folders else []
    for key, group in (("systems", "system"), ("models", "model")):
        if c[key] == "all" or c[key] == ["all"]:
            c[key] = catalogue(group)  # a model a system cannot serve fails with its one-line reason
    per_system = c.get("per_system") or {}
    per_model = c.get("per_model") or {}
    per_family = c.get("per_family") or {}
    by_name = [m for m in (*c["models"], *c["n_train_models"]) if isinstance(m, str)]
    family = {m: family_overrides(m, per_family, searched) for m in dict.fromkeys(by_name)}  # after common: refine it
    # an entry: system, label, overrides before common, n_train, published numbers, overrides after common
    entries: list[tuple[Any, ...]] = [
        (s, m, [f"model={m}", *per_model.get(m, [])], None, {}, family[m]) for s in c["systems"] for m in c["models"]
    ]
    entries += [(r["system"], r["label"], list(r["overrides"]), None, r.get("paper", {}), []) for r in c["runs"]]
    efficiency_systems = c["n_train_system"] if isinstance(c["n_train_system"], list) else [c["n_train_system"]]
    per_n = {int(k): list(v) for k, v in (c.get("per_n_train") or {}).items()}
    for n in c["n_train"]:
        if n < 1:
            raise ConfigError(f"n_train={n}; allowed: training-set sizes >= 1")
        for system in efficiency_systems:
            for m in c["n_train_models"] or c["models"]:  # a model name, or {label, overrides} (e.g. an integrator)
                label, ovr, after = (
                    (m, [f"model={m}", *per_model.get(m, [])], family[m])
                    if isinstance(m, str)
                    else (m["label"], list(m["overrides"]), [])
                )
                entries.append((system, label, [*ovr, f"data.n_train={n}", *per_n.get(n, [])], n, {}, after))
    if c.get("only"):  # a part of the profile: entries whose system or system/label is listed
        entries = [e for e in entries if e[0] in c["only"] or f"{e[0]}/{e[1]}" in c["only"]]
        if not entries:
            raise ConfigError(
                f"only={c['only']} selects none of the profile's runs; allowed: its systems or system/label pairs"
            )
    if not entries:
        raise ConfigError("profile has no runs: give systems and models, runs or n_train")
    yielded = preset_keys(c["train"])  # the profile's overrides of what a train=[debug=...] preset sets: dropped

    def kept(overrides: list[str]) -> list[str]:
        return [o for o in overrides if o.partition("=")[0].lstrip("+~") not in yielded]

    return [
        PlannedRun(
            system,
            label,
            seed,
            [
                *searched,
                f"system={system}",
                *kept([*ovr, *c["common"], *after, *per_system.get(system, [])]),
                f"seed={seed}",
                f"threads={json.dumps(c['threads'])}",
                *c["train"],
            ],
            n,
            paper,
        )
        for system, label, ovr, n, paper, after in entries
        for seed in c["seeds"]
    ]


def preset_keys(train: list[str]) -> set[str]:
    """The keys a ``debug=<preset>`` among a benchmark's ``train`` overrides sets (``conf/debug/<preset>.yaml``),
    and ``data.chunk_len`` when it sets ``data.n_steps`` (a profile's window must not outgrow the preset's
    trajectories). A group choice loses to any key override, wherever given, so without this a profile's
    ``trainer.max_epochs=1000`` beat ``train=[debug=fast]`` and its ``data.chunk_len=30`` failed every run."""
    from omegaconf import OmegaConf

    keys: set[str] = set()
    for item in train:
        group, _, choice = item.partition("=")
        path = Path(config_dir()) / "debug" / f"{choice}.yaml"
        if group != "debug" or not path.is_file():
            continue
        preset = cast("dict[str, Any]", OmegaConf.to_container(OmegaConf.load(path)))  # a YAML mapping: a dict
        stack = [("", {k: v for k, v in preset.items() if k not in ("defaults", "preset_keys")})]
        while stack:
            prefix, node = stack.pop()
            for key, value in node.items():
                (stack.append((f"{prefix}{key}.", value)) if isinstance(value, dict) else keys.add(f"{prefix}{key}"))
        if "data.n_steps" in keys:
            keys.add("data.chunk_len")
    return keys


def family_overrides(model: str, per_family: dict, searched: Sequence[str] = ()) -> list[str]:
    """The overrides ``per_family`` gives ``model``'s family: the ``family`` its class declares
    (``DynamicsModel.family``, e.g. ``constrained`` for CHNN and CLNN). A profile with ``per_family`` refuses a
    model whose family it does not list, so no model falls back to another setting unseen."""
    if not per_family:
        return []
    from encons.config import trust
    from encons.training.build import compose

    family = trust.locate(compose([*searched, f"model={model}"]).model._target_, "model").family
    if family not in per_family:
        raise ConfigError(
            f"per_family has no entry for model={model} (family {family}); allowed: one entry per "
            f"family of the profile's models, listed: {', '.join(per_family)}"
        )
    return list(per_family[family])


def check_keys(c: dict) -> None:
    """Refuse seeds (the check of a seed ensemble's: a cell's seeds train as one), threads and an output folder
    that cannot work, naming the key and what is allowed."""
    from encons.config.check import check_seeds

    check_seeds(c["seeds"])
    threads.choose(c.get("threads"))  # the thread policy refuses what it does not take, in its own words
    blocking = next((p for p in (Path(c["out"]), *Path(c["out"]).parents) if p.exists() and not p.is_dir()), None)
    if blocking is not None:
        raise ConfigError(f"out={c['out']!r}: {str(blocking)!r} is a file; allowed: a folder for the runs and report")


def finished(run: PlannedRun, out: Path) -> Path:
    """Where ``run`` leaves its result row; the run is finished when the file exists."""
    return out / "runs" / run.id / "result.json"


def run_one(run: PlannedRun, out: Path, cache_dir: str | None, control: bool = False) -> dict:
    """Train and test ``run`` (``encons.training.runs.train``; with ``control`` also score its controller beside the
    oracle, ``encons.tools.control``: ``test/control/*``, ``test/oracle/*``); write and return its result row."""
    from encons.training import runs
    from encons.training.build import compose

    done = finished(run, out)
    run_dir = done.parent
    # first, so a profile or the command line may turn the model table back on
    cfg = compose(["trainer.enable_model_summary=false", *run.overrides], run_dir, cache_dir)
    resume_or_clear(cfg, run_dir / "checkpoints")
    started = time.perf_counter()
    try:
        trained = runs.train(cfg, summary=False)
        # training and test (a resumed run: its segments before the checkpoint it resumed from too)
        results, error, wall = dict(trained.metrics), "", trained.metrics["wall_time_s"]
        # a planned run is one seed's (a cell's seeds train together through ensemble.train): a Run
        one = cast("Run", trained)
        steps = one.module.trainer.global_step
        shown = declared_headline(one.module, control)
        if control:
            from encons.tools.control import score_control

            results.update({f"test/{k}": v for k, v in score_control(trained).items()})
    except Interrupted as err:  # stops the benchmark; its rerun resumes this run (resume_or_clear)
        raise Interrupted(
            f"{run.id}: {str(err).split(';')[0]}; rerun the same benchmark command: finished runs "
            f"are skipped and this one resumes from its last.ckpt",
            err.status,
        ) from None
    except EnconsError as err:
        results, error, wall, steps, shown = {}, str(err), time.perf_counter() - started, None, []
    row = result_row(run, cfg, out, run_dir, error, wall, steps, results, shown)
    write_json(done, row, indent=1)  # atomic: a run killed before it is rerun
    return row


def run_ensemble(members: list[PlannedRun], out: Path, cache_dir: str | None, control: bool = False) -> list[dict]:
    """Train the seeds of one cell as one ensemble (``encons.training.ensemble``: each member the run of its seed) and
    write each member's result row into its own ``runs/<id>/`` (its checkpoints, curves and figures there too),
    as ``run_one`` would; ``wall_time_s`` is the whole ensemble's (``Ensemble.wall_time_s``). A member that
    diverged is a failed row."""
    from encons.training import ensemble, runs
    from encons.training.build import Request, compose

    first = members[0]
    overrides = [o for o in first.overrides if not o.startswith("seed=")]
    seeds = [m.seed for m in members]
    by_seed = {m.seed: m for m in members}
    ens_dir = out / "runs" / f"{first.cell}-seeds{'-'.join(map(str, seeds))}"
    cfg = compose(["trainer.enable_model_summary=false", *overrides, f"seeds={json.dumps(seeds)}"], ens_dir, cache_dir)
    resume_or_clear(cfg, ens_dir / "checkpoints")  # an interrupted ensemble resumes from its last.ckpt
    if cfg.ckpt_path is None:  # a fresh start: its members' earlier best checkpoints go too
        for m in members:
            shutil.rmtree(finished(m, out).parent / "checkpoints", ignore_errors=True)
    started = time.perf_counter()
    try:
        with runs.log_file(ens_dir / "train.log"):
            trained = ensemble.train(
                cfg, False, Request.of(cfg), member_dir=lambda seed: finished(by_seed[seed], out).parent
            )
        wall, error = trained.wall_time_s, ""  # the segments before a resume too
    except Interrupted as err:
        raise Interrupted(
            f"{first.cell}: {str(err).split(';')[0]}; rerun the same benchmark command: finished "
            f"runs are skipped and this ensemble resumes from its last.ckpt",
            err.status,
        ) from None
    except EnconsError as err:
        trained, wall, error = None, time.perf_counter() - started, str(err)
    rows = []
    for i, m in enumerate(members):
        results, why = {}, error
        if trained is not None:
            member = trained.members[i]
            results, why = dict(member.metrics), trained.diverged.get(m.seed, "")
            if control and not why:
                from encons.tools.control import score_control

                results.update({f"test/{k}": v for k, v in score_control(member).items()})
        steps = trained.members[i].module.trainer.global_step if trained is not None and not why else None
        shown = declared_headline(trained.members[i].module, control) if trained is not None and not why else []
        ensemble_path = f"{len(members)} seeds, {trained.path if trained else 'failed'}"
        row = result_row(m, cfg, out, finished(m, out).parent, why, wall, steps, results, shown, ensemble=ensemble_path)
        write_json(finished(m, out), row, indent=1)
        rows.append(row)
    return rows


def result_row(
    run: PlannedRun,
    cfg: DictConfig,
    out: Path,
    run_dir: Path,
    error: str,
    wall: float,
    steps: int | None,
    results: dict,
    shown: list[str],
    **after_wall: str,
) -> dict:
    """One run's result row (``runs/<id>/result.json``), as ``run_one`` and ``run_ensemble`` write it: what it is,
    its folder and overrides as the report records them, its error, wall time (then ``after_wall``, e.g. the
    ensemble's path), optimiser, test and validation metrics, and the headline it declares."""
    return {
        "system": run.system,
        "model": run.label,
        "seed": run.seed,
        "n_train": cfg.data.n_train,
        "data_efficiency": run.n_train is not None,
        "run_dir": recorded(run_dir, out),
        "error": error,
        "wall_time_s": wall,
        **after_wall,
        "overrides": " ".join(recorded_override(o, out) for o in run.overrides),
        "optimiser": optimiser(cfg, steps),
        **{k: v for k, v in results.items() if k.startswith(("test/", "val/"))},
        "headline": shown,
    }


def declared_headline(module, control: bool = False) -> list[str]:
    """The metrics a run's summary headline shows, as its result row records them (``encons.tools.report.headline``):
    ``wall_time_s``, what its evaluators and its model declare (``Evaluator.headline``, ``DynamicsModel.headline``)
    and, with ``control``, the control tool's (``encons.tools.control.HEADLINE``)."""
    names = [*(k for e in module.evaluators.values() for k in e.headline), *module.model.headline]
    if control:
        from encons.tools.control import HEADLINE

        names += HEADLINE
    return ["wall_time_s", *dict.fromkeys(f"test/{k}" for k in names)]


def optimiser(cfg: DictConfig, steps: int | None = None) -> str:
    """The optimiser, its lr and weight decay, the schedule and the epochs (and optimiser ``steps``, where
    known: what an epoch is differs between data protocols) a run trained with, as the report's optimiser
    column shows them (class names of the ``optimizer`` and ``scheduler`` configs)."""
    o, s = cfg.optimizer, cfg.get("scheduler")
    name = str(o._target_).rsplit(".", 1)[-1]
    keys = ", ".join(f"{k} {v:g}" for k, v in o.items() if not k.startswith("_") and isinstance(v, (int, float)))
    schedule = (
        "constant lr"
        if not s
        else str(s._target_).rsplit(".", 1)[-1]
        + "".join(f", {k} {v:g}" for k, v in s.items() if not k.startswith("_") and isinstance(v, (int, float)))
    )
    return f"{name} {keys}; {schedule}; {cfg.trainer.max_epochs} epochs" + (f" ({steps} steps)" if steps else "")


def resume_or_clear(cfg: DictConfig, checkpoints: Path) -> None:
    """An interrupted run (its ``last.ckpt``, no result) resumes where it stopped, as ``ckpt_path`` does
    for one run, in whichever of its attempts (``encons.training.attempts``: the plain inverse or the guarded solve)
    wrote it; checkpoints of another config (the profile changed since) are removed: a fresh start."""
    from encons.infra import checkpoints as ckpts
    from encons.training import attempts
    from encons.training.build import Request

    last = checkpoints / "last.ckpt"
    try:
        diffs = (
            [ckpts.difference(a.cfg, last) for a in attempts.plan(cfg, Request())]
            if last.is_file()
            else ["no last.ckpt"]
        )
        diff = None if None in diffs else diffs[0]
    except ConfigError as err:  # an unreadable or unsafe checkpoint is a fresh start
        diff = f"last.ckpt refused: {err}"
    if diff is None:
        cfg.ckpt_path = str(last)
        print(f"  resuming from {last}", flush=True)
    elif checkpoints.is_dir():
        shutil.rmtree(checkpoints)
        print(f"  earlier checkpoints removed ({diff}): training afresh", flush=True)


def result_line(row: dict) -> str:
    """The headline of a finished run: its test errors and wall time (every metric: its result.json)."""
    keys = (
        "test/traj_rel_err",
        "test/geom_rel_err",
        "test/energy_abs_err",
        "test/diverged",
        "test/control/success_rate",
        "test/oracle/success_rate",
    )
    shown = [f"{k.removeprefix('test/')} {row[k]:.3g}" for k in keys if k in row]
    return ", ".join(shown + [f"{row['wall_time_s']:.0f} s"])


def run_profile(cfg: DictConfig) -> Path:
    """PlannedRun every run of ``cfg`` not yet finished under ``cfg.out``, then write the report there."""
    from encons.infra.progress import Progress
    from encons.tools.report import load_rows, write_report

    runs = expand(cfg)
    out = Path(cfg.out)
    write_yaml(out / "benchmark.yaml", recorded_config(plain(cfg), out))
    cache_dir = cfg.get("cache_dir")
    todo = [run for run in runs if not finished(run, out).is_file()]
    progress = Progress(len(runs), "benchmark run", work=len(todo))  # the ETA counts runs still to train
    cells: dict[str, list[PlannedRun]] = {}
    for run in runs:
        cells.setdefault(run.cell, []).append(run)
    for members in cells.values():
        for run in [m for m in members if finished(m, out).is_file()]:
            progress.start(f"{run.id}: finished before, skipped", work=0)
        members = [m for m in members if not finished(m, out).is_file()]
        if not members:
            continue
        progress.start(
            members[0].id if len(members) == 1 else f"{members[0].cell}, seeds {[m.seed for m in members]}",
            work=len(members),
            items=len(members),
        )
        rows = (
            [run_one(members[0], out, cache_dir, bool(cfg.get("control")))]
            if len(members) == 1
            else run_ensemble(members, out, cache_dir, bool(cfg.get("control")))
        )
        for run, row in zip(members, rows):
            if row["error"]:
                print(f"{run.id} failed: {row['error']}", file=sys.stderr)
            else:
                print(f"{run.id}: {result_line(row)}", flush=True)
    progress.done()
    write_report(out)
    print(f"report: {out / 'summary.md'} (tables, figures and results.csv in {out})", flush=True)
    errors = [row.get("error") for row in load_rows(out)]
    if all(errors):
        raise ConfigError(
            f"{errors[0]}; every one of the {len(errors)} benchmark runs failed (errors: {out / 'results.csv'})"
        )
    return out


def usage() -> str:
    """``--help``: this module's usage, the profiles found in ``conf/profile`` and the keys of
    ``conf/benchmark.yaml``."""
    profiles = sorted(p.stem for p in (Path(config_dir()) / "profile").glob("*.yaml"))
    keys = (Path(config_dir()) / "benchmark.yaml").read_text()
    return f"{__doc__}\nprofiles: {', '.join(profiles)}\n\nconf/benchmark.yaml:\n{keys}"
