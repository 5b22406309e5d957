"""The one entry room: every command's argv handling, as plain functions.

    python -m encons train model=<model> system=<system> [overrides]    (encons-train, python -m encons.train)
    python -m encons evaluate RUN_DIR|CKPT [ckpt=best|last|PATH] [overrides]
                                                                        (encons-evaluate, python -m encons.evaluate)
    python -m encons benchmark [profile=NAME] [overrides]               (encons-benchmark, python -m encons.benchmark)
    python -m encons report DIR                                         (encons-report, python -m encons.report)
    python -m encons sweep STORAGE STUDY [OUT]                          (python -m encons.sweep)
    python -m encons control RUN [ckpt=…] [starts=…] [seed=…] [duration=…]   (python -m encons.control)

:func:`main` dispatches ``python -m encons <command>`` (``encons/__main__.py``); the console scripts
call the command functions directly; ``python -m encons.<command>`` is an alias of the same
(``encons.aliases``). Each wraps one library function in :func:`encons.infra.errors.one_line_errors`: a
user's error is one line on stderr and exit status 2; a bug keeps its traceback. What must exist
before Hydra composes anything (the resolvers of ``conf/``) is registered here, and Hydra's
process-global state is read here, at the top, and passed down explicitly (``encons.config.check.Request``).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from contextlib import nullcontext

from omegaconf import DictConfig

from encons.config.check import Request, apply_presets
from encons.config.trust import TRUST_VARIABLE, trusted_targets
from encons.infra.compat import quiet_upstream
from encons.infra.errors import ConfigError, one_line_errors
from encons.infra.paths import config_dir

EVALUATE_USAGE = """Roll out a trained run's checkpoint on a test set: metrics, figures, summary table.

    python -m encons.evaluate RUN_DIR|CKPT [ckpt=best|last|PATH] [key=value ...]

``RUN_DIR`` is a training run's output folder (``checkpoints/``); a ``.ckpt`` file works alone,
since checkpoints carry their config. ``ckpt=best`` (default) is the checkpoint ``train`` tested,
so the metrics agree to the digit. Overrides change the evaluation, e.g. ``data.test_steps=1000``
for a longer test set; metrics sum over the first ``horizon`` steps (4), so add
``horizon=1000`` to score the whole trajectory. Results land in ``RUN_DIR/evaluation/``.
"""


def register_resolvers() -> None:
    """The OmegaConf resolvers ``conf/`` uses, registered before Hydra composes (and instantiates its
    launcher): ``${encons_threads:...}`` (``conf/hydra/launcher/parallel.yaml``) and ``${encons_help_groups:}``."""
    from encons.entry import help
    from encons.infra import threads

    help.register()
    threads.register()


def train_job(cfg: DictConfig) -> float | None:
    """One Hydra job: train ``cfg`` and return its ``optimized_metric`` (best checkpoint's value) for a sweep.

    A config that sets ``ENCONS_TRUSTED_TARGETS`` through ``hydra.job.env_set`` is refused: the trust
    list is the user's environment, never a file's.
    """
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    from encons.training import runs

    hydra = HydraConfig.get()
    # a single run reports a user's error here, before Hydra adds its own "Error executing job" line;
    # in a sweep the error goes to the sweeper, which records the trial as failed and goes on
    with one_line_errors() if hydra.mode == RunMode.RUN else nullcontext():
        if TRUST_VARIABLE in (hydra.job.env_set or {}):
            raise ConfigError(
                f"hydra.job.env_set.{TRUST_VARIABLE} is set by a config; allowed: "
                f"{TRUST_VARIABLE} in the environment that starts encons (a config cannot widen trust)"
            )
        request = Request(dict(hydra.runtime.choices), tuple(hydra.overrides.task))
        apply_presets(
            cfg, request
        )  # as encons.training.build.compose does: the config as composed, before it is checked
        results = runs.train(cfg, request=request).metrics
    return results.get(f"best/{cfg.optimized_metric}", results.get(cfg.optimized_metric))


def train() -> None:
    """``python -m encons.train``: Hydra's command line (``-m`` for sweeps) around :func:`train_job`."""
    import hydra

    register_resolvers()
    empty = next((a for a in sys.argv[1:] if "=" in a and not a.startswith("-") and a.endswith("=")), None)
    if empty:  # e.g. hydra.sweeper.sampler.seed=$K with K unset: Hydra's own error has no "allowed:" part
        with one_line_errors():
            raise ConfigError(
                f"{empty} has no value (an unset shell variable?); allowed: {empty}VALUE, or {empty}null for none"
            )
    os.environ.setdefault("WANDB_SILENT", "true")
    quiet_upstream()
    # Hydra then lets its own errors through to us (else it prints them with its search path and
    # exits 1): a user's error becomes the last line printed, a bug keeps its traceback.
    os.environ["HYDRA_FULL_ERROR"] = "1"
    main = hydra.main(config_path=config_dir(), config_name="train", execution_whitelist=trusted_targets())(train_job)
    with one_line_errors():
        main()


def evaluate(argv: list[str] | None = None) -> None:
    """``python -m encons.evaluate RUN_DIR|CKPT [ckpt=...] [overrides]``."""
    from encons.training import runs

    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):
        print(EVALUATE_USAGE)
        sys.exit(0 if argv else 2)
    quiet_upstream()
    overrides = [a for a in argv[1:] if not a.startswith("ckpt=")]
    ckpt = next((a.split("=", 1)[1] for a in argv[1:] if a.startswith("ckpt=")), "best")
    with one_line_errors():
        if not os.path.exists(argv[0]):
            raise ConfigError(f"{argv[0]!r} does not exist; allowed: a run folder that train wrote, or its .ckpt")
        runs.evaluate(argv[0], overrides, ckpt=ckpt)


def benchmark(argv: list[str] | None = None) -> None:
    """``python -m encons.benchmark [overrides]``: every run of a profile, then the report."""
    import logging

    from encons.tools import benchmark as bench
    from encons.training.build import compose

    register_resolvers()
    os.environ.setdefault("WANDB_MODE", "disabled")
    quiet_upstream()
    import lightning.pytorch  # noqa: F401 - its import sets its loggers' level: quieten them after it

    for name in (
        "lightning.pytorch",
        "lightning.fabric",
    ):  # devices, stop reason, checkpoint restored: per run, not news
        logging.getLogger(name).setLevel(logging.WARNING)
    args = list(sys.argv[1:] if argv is None else argv)
    if {"-h", "--help"} & set(args):
        print(bench.usage())
        return
    with one_line_errors():
        bench.run_profile(compose(args, config_name="benchmark"))


def sweep_report(argv: list[str] | None = None) -> None:
    """``python -m encons.sweep STORAGE STUDY [OUT]``: the report of a stored study, e.g. after
    several workers shared it."""
    import argparse
    from pathlib import Path

    from encons.tools import sweep

    parser = argparse.ArgumentParser(prog="python -m encons.sweep", description=sweep_report.__doc__)
    parser.add_argument("storage", help="SQLAlchemy URL, e.g. sqlite:///multirun/NAME/optuna.db")
    parser.add_argument("study")
    parser.add_argument("out", nargs="?", default=".", help="folder for trials.csv and figures")
    args = parser.parse_args(argv)
    with one_line_errors():
        sweep.report(sweep.load_study(args.storage, args.study), Path(args.out))


def report(argv: list[str] | None = None) -> None:
    """``python -m encons.report DIR``: a benchmark's or a multirun's report, rebuilt without training."""
    from pathlib import Path

    from encons.tools import report as rep

    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--docs"]:  # the README's and docs/' result tables from benchmarks/reports/
        from encons.tools import docs

        with one_line_errors():
            for path in docs.write():
                print(path)
        return
    if len(argv) != 1 or argv[0] in ("-h", "--help"):
        print(rep.__doc__)
        sys.exit(0 if len(argv) == 1 else 2)
    with one_line_errors():
        for path in rep.write_folder_report(Path(argv[0])):
            print(path)


def control(argv: list[str] | None = None) -> None:
    """``python -m encons.control RUN [ckpt=…] [starts=…] [seed=…] [duration=…]``: the run's swing-up
    controller scored beside the oracle's (:func:`encons.tools.control.score_control`)."""
    from encons.tools import control as ctl

    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(ctl.__doc__)
        sys.exit(0 if argv else 2)
    quiet_upstream()
    kinds = {"ckpt": str, "starts": int, "seed": int, "duration": float}
    with one_line_errors():
        options = {}
        for arg in argv[1:]:
            key, eq, value = arg.partition("=")
            if not eq or key not in kinds:
                raise ConfigError(
                    f"{arg} is not an option of encons.tools.control; allowed: {', '.join(f'{k}=…' for k in kinds)}"
                )
            try:
                options[key] = kinds[key](value)
            except ValueError:
                raise ConfigError(
                    f"{key}={value} is not a{'n integer' if kinds[key] is int else ' number'}; "
                    f"allowed: {kinds[key].__name__} values"
                ) from None
        ctl.score_control(argv[0], **options)


#: ``python -m encons <command>``: each command's function.
COMMANDS: dict[str, Callable[..., None]] = {
    "train": train,
    "evaluate": evaluate,
    "benchmark": benchmark,
    "report": report,
    "sweep": sweep_report,
    "control": control,
}
USAGE = "usage: python -m encons {" + ",".join(COMMANDS) + "} [arguments]   (python -m encons <command> --help)"


def main(argv: list[str] | None = None) -> None:
    """``python -m encons <command> [arguments]``: the command's function with the rest of the command line
    (Hydra's ``train`` reads ``sys.argv``, so it is set to the command's own)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(USAGE)
        sys.exit(0 if argv else 2)
    if argv[0] not in COMMANDS:
        print(f"encons: error: command {argv[0]!r} does not exist; allowed: {', '.join(COMMANDS)}", file=sys.stderr)
        sys.exit(2)
    command, rest = COMMANDS[argv[0]], argv[1:]
    if command is train:
        sys.argv = [f"{sys.argv[0]} train", *rest]
        train()
    else:
        command(rest)
