"""Benchmark runner: the runs of a profile (conf/profile/*.yaml), trained one by one, then the report.

    python -m encons.benchmark [profile=smoke|quick|zhong|finzi|lim_kasim|pixels|control] [seeds=[0,1]] [out=DIR]
        ['train=["trainer.max_epochs=50"]']   (quoted: Hydra's grammar wants '=' inside a list quoted)

A profile lists its runs as a grid (``systems`` × ``models``), as explicit ``runs`` (a label and
its train overrides, e.g. a model with a regulariser) and as data-efficiency runs (``n_train``);
each is trained ``len(seeds)`` times through the training entry point, on datasets cached under
``paths.cache_dir`` (one per system and data config, shared by every model and seed). A finished
run leaves ``runs/<id>/result.json``; a rerun skips it, so an interrupted benchmark resumes where it
stopped. Progress (stdout, the stream a run logs to) prints ``benchmark run k of n (id), elapsed, ETA``. ``models=all`` /
``systems=all`` take every option of ``conf/model`` / ``conf/system``. The report (``encons.report``) is written
to ``out`` at the end and can be rebuilt alone with ``python -m encons.report OUT``.
"""

from __future__ import annotations

import json
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.errors import MissingConfigException
from omegaconf import DictConfig, OmegaConf

from encons import threads
from encons.errors import ConfigError, EnconsError, Interrupted
from encons.io import write_json, write_yaml
from encons.paths import config_dir


@dataclass
class Run:
    """One training run of a benchmark: ``label`` is the model column of the tables."""

    system: str
    label: str
    seed: int
    overrides: list[str]
    n_train: int | None = None
    paper: dict = field(default_factory=dict)

    @property
    def id(self) -> str:
        size = f"-n{self.n_train}" if self.n_train is not None else ""
        return f"{self.system}-{self.label}{size}-seed{self.seed}".replace("/", "_").replace("'", "p")


def compose_benchmark(overrides: list[str]) -> DictConfig:
    """``conf/benchmark.yaml`` with its profile and the command line's overrides."""
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=config_dir(), job_name="benchmark"):
        try:
            cfg = compose("benchmark", overrides=list(overrides), return_hydra_config=True)
        except MissingConfigException:
            profiles = sorted(p.stem for p in (Path(config_dir()) / "profile").glob("*.yaml"))
            bad = next((o for o in overrides if o.startswith("profile=")), "profile=?")
            raise ConfigError(f"{bad} is unknown; allowed: {', '.join(profiles)}") from None
    from hydra.core.hydra_config import HydraConfig

    HydraConfig.instance().set_config(cfg)
    return cfg


def plain(cfg: DictConfig) -> dict:
    """The benchmark config without Hydra's own node, resolved."""
    return {k: OmegaConf.to_container(cfg[k], resolve=True) if OmegaConf.is_config(cfg[k]) else cfg[k]
            for k in cfg if k != "hydra"}


def expand(cfg: DictConfig) -> list[Run]:
    """Every run of the profile: grid, listed runs and data-efficiency runs, times seeds."""
    from encons.api import catalogue

    c = plain(cfg)
    check_keys(c)
    for key, group in (("systems", "system"), ("models", "model")):
        if c[key] == "all" or c[key] == ["all"]:
            c[key] = catalogue(group)  # a model a system cannot serve fails with its one-line reason
    per_system = c.get("per_system") or {}
    entries = [(s, m, [f"model={m}"], None, {}) for s in c["systems"] for m in c["models"]]
    entries += [(r["system"], r["label"], list(r["overrides"]), None, r.get("paper", {})) for r in c["runs"]]
    for n in c["n_train"]:
        if n < 1:
            raise ConfigError(f"n_train={n}; allowed: training-set sizes >= 1")
        for m in c["n_train_models"] or c["models"]:
            entries.append((c["n_train_system"], m, [f"model={m}", f"data.n_train={n}"], n, {}))
    if not entries:
        raise ConfigError("profile has no runs: give systems and models, runs or n_train")
    return [Run(system, label, seed, [f"system={system}", *ovr, *c["common"], *per_system.get(system, []),
                                     f"seed={seed}", f"threads={json.dumps(c['threads'])}", *c["train"]], n, paper)
            for system, label, ovr, n, paper in entries for seed in c["seeds"]]


def check_keys(c: dict) -> None:
    """Refuse seeds, threads and an output folder that cannot work, naming the key and what is allowed."""
    seeds = c["seeds"]
    if not isinstance(seeds, list) or not seeds or not all(
            isinstance(s, int) and not isinstance(s, bool) and 0 <= s < 2**32 for s in seeds):
        raise ConfigError(f"seeds={seeds}; allowed: a non-empty list of integer seeds in 0..2**32-1, e.g. seeds=[0,1]")
    threads.choose(c.get("threads"))  # the thread policy refuses what it does not take, in its own words
    blocking = next((p for p in (Path(c["out"]), *Path(c["out"]).parents) if p.exists() and not p.is_dir()), None)
    if blocking is not None:
        raise ConfigError(f"out={c['out']!r}: {str(blocking)!r} is a file; allowed: a folder for the runs and report")


def finished(run: Run, out: Path) -> Path:
    """Where ``run`` leaves its result row; the run is finished when the file exists."""
    return out / "runs" / run.id / "result.json"


def run_one(run: Run, out: Path, cache_dir: str | None, control: bool = False) -> dict:
    """Train and test ``run`` through ``encons.api`` (and with ``control`` score its controller beside the
    oracle, ``encons.control``: ``test/control/*``, ``test/oracle/*``); write and return its result row."""
    from encons import api

    done = finished(run, out)
    run_dir = done.parent
    # first, so a profile or the command line may turn the model table back on
    cfg = api.compose("trainer.enable_model_summary=false", *run.overrides, output_dir=run_dir, cache_dir=cache_dir)
    resume_or_clear(cfg, run_dir / "checkpoints")
    started = time.perf_counter()
    try:
        trained = api.train(cfg, summary=False)
        results, error, wall = dict(trained.metrics), "", time.perf_counter() - started  # training time only
        if control:
            from encons.control import score_control

            results.update({f"test/{k}": v for k, v in score_control(trained).items()})
    except Interrupted as err:  # stops the benchmark; its rerun resumes this run (resume_or_clear)
        raise Interrupted(f"{run.id}: {str(err).split(';')[0]}; rerun the same benchmark command: finished runs "
                          f"are skipped and this one resumes from its last.ckpt") from None
    except EnconsError as err:
        results, error, wall = {}, str(err), time.perf_counter() - started
    row = {"system": run.system, "model": run.label, "seed": run.seed, "n_train": cfg.data.n_train,
           "data_efficiency": run.n_train is not None, "run_dir": str(run_dir), "error": error,
           "wall_time_s": wall, "overrides": " ".join(run.overrides),
           **{k: v for k, v in results.items() if k.startswith(("test/", "val/"))}}
    write_json(done, row, indent=1)  # atomic: a run killed before it is rerun
    return row


def resume_or_clear(cfg: DictConfig, checkpoints: Path) -> None:
    """An interrupted run (its ``last.ckpt``, no result) resumes where it stopped, as ``ckpt_path`` does
    for one run; checkpoints of another config (the profile changed since) are removed: a fresh start."""
    from encons.config import checkpoint_difference

    last = checkpoints / "last.ckpt"
    try:
        diff = checkpoint_difference(cfg, last) if last.is_file() else "no last.ckpt"
    except Exception as err:  # noqa: BLE001 - any unreadable checkpoint is a fresh start
        diff = f"last.ckpt unreadable: {type(err).__name__}"
    if diff is None:
        cfg.ckpt_path = str(last)
        print(f"  resuming from {last}", flush=True)
    elif checkpoints.is_dir():
        shutil.rmtree(checkpoints)
        print(f"  earlier checkpoints removed ({diff}): training afresh", flush=True)


def result_line(row: dict) -> str:
    """The headline of a finished run: its test errors and wall time (every metric: its result.json)."""
    keys = ("test/traj_rel_err", "test/geom_rel_err", "test/energy_abs_err", "test/diverged",
            "test/control/success_rate", "test/oracle/success_rate")
    shown = [f"{k.removeprefix('test/')} {row[k]:.3g}" for k in keys if k in row]
    return ", ".join(shown + [f"{row['wall_time_s']:.0f} s"])


def run_profile(cfg: DictConfig) -> Path:
    """Run every run of ``cfg`` not yet finished under ``cfg.out``, then write the report there."""
    from encons.report import Progress, load_rows, write_report

    runs = expand(cfg)
    out = Path(cfg.out)
    write_yaml(out / "benchmark.yaml", plain(cfg))
    cache_dir = cfg.get("cache_dir")
    todo = [run for run in runs if not finished(run, out).is_file()]
    progress = Progress(len(runs), "benchmark run", work=len(todo))  # the ETA counts runs still to train
    for run in runs:
        if finished(run, out).is_file():
            progress.start(f"{run.id}: finished before, skipped", work=0)
            continue
        progress.start(run.id)
        row = run_one(run, out, cache_dir, bool(cfg.get("control")))
        if row["error"]:
            print(f"{run.id} failed: {row['error']}", file=sys.stderr)
        else:
            print(f"{run.id}: {result_line(row)}", flush=True)
    progress.done()
    write_report(out)
    errors = [row.get("error") for row in load_rows(out)]
    if all(errors):
        raise ConfigError(f"{errors[0]}; every one of the {len(errors)} benchmark runs failed (errors: {out / 'results.csv'})")
    return out


def usage() -> str:
    """``--help``: this module's usage, the profiles found in ``conf/profile`` and the keys of ``conf/benchmark.yaml``."""
    profiles = sorted(p.stem for p in (Path(config_dir()) / "profile").glob("*.yaml"))
    keys = (Path(config_dir()) / "benchmark.yaml").read_text()
    return f"{__doc__}\nprofiles: {', '.join(profiles)}\n\nconf/benchmark.yaml:\n{keys}"


def main(argv: list[str] | None = None) -> None:
    import logging
    import os

    from encons import api
    from encons.errors import one_line_errors

    os.environ.setdefault("WANDB_MODE", "disabled")
    api.quiet_upstream()
    import lightning.pytorch  # noqa: F401 - its import sets its loggers' level: quieten them after it

    for name in ("lightning.pytorch", "lightning.fabric"):  # devices, stop reason, checkpoint restored: per run, not news
        logging.getLogger(name).setLevel(logging.WARNING)
    args = list(sys.argv[1:] if argv is None else argv)
    if {"-h", "--help"} & set(args):
        print(usage())
        return
    with one_line_errors():
        run_profile(compose_benchmark(args))


if __name__ == "__main__":
    main()
