"""Optuna sweeps through Hydra: a sweeper that records how each trial ended, the job's pruning
callback, and the end-of-sweep report.

The Hydra Optuna sweeper never hands its ``Trial`` to the job, so it cannot prune. This sweeper
passes the trial's number to the job as ``sweeps.trial=N``; the job reaches that trial through the
study's storage (:func:`pruning_callback`) and reports the validation metric every epoch. A job
that raises ``optuna.TrialPruned`` is recorded as pruned; one that raises anything else or returns
a non-finite value is recorded as failed, its reason kept in the ``fail_reason`` user attribute,
and the sweep goes on. Storage, pruner and search space are set in ``sweeps/optuna.yaml``.
"""

from __future__ import annotations

import csv
import io
import logging
import math
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, cast

import optuna
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import IntervalSweep
from hydra.core.plugins import Plugins
from hydra.core.utils import JobReturn, JobStatus
from hydra.plugins.launcher import Launcher
from hydra.plugins.sweeper import Sweeper
from hydra.types import HydraContext, TaskFunction
from hydra.utils import instantiate
from numpy.random import SeedSequence
from omegaconf import DictConfig, OmegaConf
from optuna.trial import TrialState
from sqlalchemy.engine import make_url
from sqlalchemy.exc import NoSuchModuleError, OperationalError

from encons.infra.compat import job_exception, optuna_search_space
from encons.infra.errors import ConfigError, SweepError
from encons.infra.io import save_figure, write_text, write_yaml

if TYPE_CHECKING:
    from matplotlib.figure import Figure

log = logging.getLogger(__name__)
TRIAL_KEY = "sweeps.trial"  # the job's config key that receives the trial number


class OptunaSweeper(Sweeper):
    """Asks an Optuna study for ``n_trials`` trials (``n_jobs`` at a time), launches them with the
    configured Hydra launcher and tells the study how each ended. ``enqueue``: parameter dicts
    tried first (skipped when the study already holds them). The sampler's seed is mixed with
    the number of trials already stored, so a resumed study does not repeat its first trials;
    give each concurrent worker its own ``sampler.seed``."""

    config: DictConfig  # set by setup, which Hydra calls before sweep
    launcher: Launcher

    def __init__(
        self,
        sampler: DictConfig,
        direction: str,
        storage: str | None,
        study_name: str,
        n_trials: int,
        n_jobs: int,
        max_failure_rate: float,
        params: DictConfig | None,
        enqueue: list | None = None,
    ):
        if direction not in ("minimize", "maximize"):
            raise ConfigError(f"hydra.sweeper.direction={direction!r} is unknown; allowed: minimize, maximize")
        for key, value in dict(n_trials=n_trials, n_jobs=n_jobs).items():
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ConfigError(f"hydra.sweeper.{key}={value!r}; allowed: an integer >= 1")
        if not isinstance(max_failure_rate, (int, float)) or not 0 <= max_failure_rate <= 1:
            raise ConfigError(f"hydra.sweeper.max_failure_rate={max_failure_rate!r}; allowed: a number in [0, 1]")
        self.sampler_config, self.direction, self.storage, self.study_name = sampler, direction, storage, study_name
        self.n_trials, self.n_jobs, self.max_failure_rate = n_trials, n_jobs, max_failure_rate
        # the containers of a DictConfig and a ListConfig: a dict and a list
        self.params = cast("dict[str, Any]", OmegaConf.to_container(params)) if params else {}
        self.enqueue = cast(list, OmegaConf.to_container(enqueue)) if enqueue else []

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig) -> None:
        self.config = config
        self.launcher = Plugins.instance().instantiate_launcher(
            config=config, hydra_context=hydra_context, task_function=task_function
        )

    def sweep(self, arguments: list[str]) -> None:
        check_search_space([f"{k}={v}" for k, v in self.params.items()] + list(arguments))
        space, fixed, fixed_overrides = optuna_search_space(
            [f"{k}={v}" for k, v in self.params.items()] + list(arguments)
        )
        for name in fixed:
            space.pop(name, None)
        sweep_dir = Path(self.config.hydra.sweep.dir)
        for folder in (sweep_dir, OmegaConf.select(self.config, "sweeps.dir")):  # the sweep's own output folders
            if folder is not None:
                Path(folder).mkdir(parents=True, exist_ok=True)
        study = open_study(self.storage, self.study_name, self.direction)
        study.sampler = self._sampler(len(study.trials))
        study.set_user_attr("optimized_metric", str(self.config.get("optimized_metric", "objective")))
        for params in self.enqueue:
            study.enqueue_trial(params, skip_if_exists=True)
        log.info(
            "study %s in %s: %d trials stored, %d to run",
            study.study_name,
            self.storage,
            len(study.trials),
            self.n_trials,
        )
        failed, job_idx = 0, 0
        while job_idx < self.n_trials:
            trials = [study.ask(space) for _ in range(min(self.n_jobs, self.n_trials - job_idx))]
            overrides = [
                tuple(f"{k}={v}" for k, v in {**t.params, **fixed}.items())
                + tuple(fixed_overrides)
                + (f"++{TRIAL_KEY}={t.number}",)
                for t in trials
            ]
            returns = self.launcher.launch(overrides, initial_job_idx=job_idx)
            job_idx += len(trials)
            failed += sum(_tell(study, t, r) == TrialState.FAIL for t, r in zip(trials, returns))
            if failed > self.max_failure_rate * self.n_trials:
                report(study, sweep_dir)
                first = next(
                    t.user_attrs["fail_reason"]
                    for t in study.trials
                    if t.state == TrialState.FAIL and "fail_reason" in t.user_attrs
                )
                raise SweepError(
                    f"hydra.sweeper.max_failure_rate={self.max_failure_rate}: {failed} of {job_idx} "
                    f"trials failed (first: {first.splitlines()[0]}); allowed: fix that, or a higher "
                    f"rate (reasons in {sweep_dir / 'trials.csv'})"
                )
        report(study, sweep_dir)

    def _sampler(self, n_stored: int) -> optuna.samplers.BaseSampler:
        config = cast("dict[str, Any]", OmegaConf.to_container(self.sampler_config, resolve=True))  # a dict
        if config.get("seed") is not None:
            seed = config["seed"]
            if not isinstance(seed, int) or isinstance(seed, bool) or not 0 <= seed < 2**32:
                raise ConfigError(
                    f"hydra.sweeper.sampler.seed={seed!r} (default: the run's seed); allowed: an integer in 0..2**32-1"
                )
            config["seed"] = int(SeedSequence([seed, n_stored]).generate_state(1)[0])
        try:
            sampler = instantiate(config, _execution_whitelist_=("optuna.samplers.*",))
        except Exception as err:  # noqa: BLE001 - an unknown sampler or keyword is the user's config
            cause = err.__cause__ or err
            raise ConfigError(
                f"hydra.sweeper.sampler={config.get('_target_')!r}: {type(cause).__name__}: "
                f"{str(cause).splitlines()[0] if str(cause) else ''}; allowed: hydra/sweeper/sampler="
                f"tpe | random | cmaes | gp | qmc and their keywords"
            ) from None
        if not isinstance(sampler, optuna.samplers.BaseSampler):
            raise ConfigError(
                f"hydra.sweeper.sampler={config['_target_']} needs the search space up front; "
                f"for a grid use Hydra's basic sweeper (see sweeps/model_grid.yaml)"
            )
        return sampler


def check_search_space(overrides: list[str]) -> None:
    """Refuse an ``interval(low, high)`` whose bounds are reversed (Optuna's distribution would raise), naming the
    key."""
    for override in OverridesParser.create().parse_overrides(overrides):
        value = override.value()
        if (
            isinstance(value, IntervalSweep)
            and value.start is not None
            and value.end is not None
            and value.start > value.end
        ):
            raise ConfigError(
                f"{override.get_key_element()}={override.get_value_string()} has low {value.start} > "
                f"high {value.end}; allowed: interval(low, high) with low <= high"
            )


def check_storage(storage: str) -> optuna.storages.BaseStorage:
    """The Optuna storage of a URL. An SQLite file's folder must exist (it is never created), and a
    storage whose database driver is missing, or that cannot be opened, is one ``ConfigError`` naming the fix."""
    url = make_url(storage)
    if url.get_backend_name() == "sqlite" and url.database not in (None, "", ":memory:"):
        folder = Path(url.database).parent
        if not folder.is_dir():
            raise ConfigError(
                f"sweeps.storage={storage!r}: folder {str(folder)!r} does not exist; allowed: "
                f"sqlite:///PATH in an existing folder or in sweeps.dir (created as the sweep's own), "
                f"or a database URL"
            )
    try:
        return optuna.storages.get_storage(storage)
    except (ImportError, NoSuchModuleError) as err:
        extra = {
            "postgresql": "pip install 'encons[postgres]' (psycopg 3, SQLAlchemy's driver for postgresql://)",
            "mysql": "a mysql+pymysql:// URL with pip install pymysql",
        }.get(url.get_backend_name(), "its database driver")
        raise ConfigError(
            f"sweeps.storage={storage!r}: its database driver is missing ({err.__cause__ or err}); "
            f"allowed: {extra}, or a sqlite:/// URL"
        ) from None
    except OperationalError as err:
        raise ConfigError(
            f"sweeps.storage={storage!r} cannot be opened ({str(err.orig).strip().splitlines()[0]}); "
            f"allowed: a reachable database URL, or sqlite:///PATH in a writable folder"
        ) from None


def open_study(storage: str | None, study_name: str, direction: str) -> optuna.Study:
    """Create the study, or load it when it exists (``check_storage`` first)."""
    return optuna.create_study(
        storage=check_storage(storage) if storage else None,
        study_name=study_name,
        direction=cast("Literal['minimize', 'maximize']", direction),  # Optuna refuses any other
        load_if_exists=True,
    )


def _tell(study: optuna.Study, trial: optuna.Trial, ret: JobReturn) -> TrialState:
    """Record how a launched job ended: complete with its value, pruned, or failed with a reason."""
    if ret.status == JobStatus.FAILED:
        err = job_exception(ret)
        if isinstance(err, optuna.TrialPruned):
            log.info("trial %d pruned: %s", trial.number, err)
            study.tell(trial, state=TrialState.PRUNED)
            return TrialState.PRUNED
        reason = f"{type(err).__name__}: {err}"
    elif ret.return_value is None:
        reason = "the job returned no value: is optimized_metric logged?"
    elif math.isfinite(value := float(ret.return_value)):
        log.info("trial %d: %s", trial.number, value)
        study.tell(trial, value)
        return TrialState.COMPLETE
    else:
        reason = f"objective is {value}"
    log.warning("trial %d failed: %s", trial.number, reason)
    trial.set_user_attr("fail_reason", reason)
    study.tell(trial, state=TrialState.FAIL)
    return TrialState.FAIL


def pruning_callback(
    storage: str, study_name: str, trial: int | None, monitor: str, pruner: optuna.pruners.BasePruner | None
):
    """Optuna's Lightning pruning callback for trial number ``trial`` of the stored study, judged
    by ``pruner`` (``None``: never prune) on ``monitor`` after every validation epoch."""
    from optuna_integration.pytorch_lightning import PyTorchLightningPruningCallback

    if trial is None:
        raise ConfigError(f"{TRIAL_KEY} is unset: an Optuna sweep runs with -m (python -m encons.train -m sweeps=NAME)")
    if storage is None:
        raise ConfigError(
            "sweeps.storage=null: a trial reaches its study through a storage; give an "
            "SQLAlchemy URL (sqlite:///..., postgresql://...)"
        )

    class Pruning(PyTorchLightningPruningCallback):
        def on_fit_end(self, trainer, pl_module) -> None:
            self.check_pruned()  # under DDP the callback only stops the trainer; raise here

    shared = check_storage(storage)
    trial_id = shared.get_trial_id_from_study_id_trial_number(shared.get_study_id_from_name(study_name), trial)
    study = optuna.load_study(study_name=study_name, storage=shared, pruner=pruner or optuna.pruners.NopPruner())
    return Pruning(optuna.Trial(study, trial_id), monitor)


def report(study: optuna.Study, out_dir: Path) -> None:
    """Print the best trial; save ``trials.csv``, ``optimization_results.yaml`` and figures."""
    trials = study.get_trials(deepcopy=False)
    names = sorted({k for t in trials for k in t.params})
    rows = [
        {
            "number": t.number,
            "state": t.state.name,
            "value": t.value,
            "duration_s": t.duration.total_seconds() if t.duration else None,
            "last_step": t.last_step,
            **t.params,
            "fail_reason": t.user_attrs.get("fail_reason"),
        }
        for t in trials
    ]
    table = io.StringIO()
    writer = csv.DictWriter(table, ["number", "state", "value", "duration_s", "last_step", *names, "fail_reason"])
    writer.writeheader()
    writer.writerows(rows)
    write_text(out_dir / "trials.csv", table.getvalue())
    states = [t.state for t in trials]
    counts = ", ".join(f"{s.name.lower()} {states.count(s)}" for s in TrialState if states.count(s))
    complete = [t for t in trials if t.state == TrialState.COMPLETE]
    if not complete:
        print(f"study {study.study_name}: no complete trial ({counts}); table: {out_dir / 'trials.csv'}")
        return
    best = study.best_trial
    results = {
        "study": study.study_name,
        "best_trial": best.number,
        "best_value": best.value,
        "best_params": best.params,
    }
    write_yaml(out_dir / "optimization_results.yaml", results)
    _save_figures(study, out_dir, plot_importance=len(complete) > 1 and len(names) > 0)
    print(
        f"study {study.study_name}: {len(trials)} trials ({counts})\n"
        f"best trial {best.number}: value {best.value:.6g}\n"
        f"best params: {' '.join(f'{k}={v}' for k, v in best.params.items())}\n"
        f"table and figures: {out_dir}"
    )


def _save_figures(study: optuna.Study, out_dir: Path, plot_importance: bool) -> None:
    import matplotlib.pyplot as plt
    from optuna.visualization import matplotlib as vis

    metric = study.user_attrs.get("optimized_metric", "objective")  # each trial's best-checkpoint value
    plots = {"optimization_history": lambda s: vis.plot_optimization_history(s, target_name=metric)}
    if plot_importance:
        plots["param_importances"] = lambda s: vis.plot_param_importances(s, target_name=metric)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        for name, plot in plots.items():
            try:
                fig = cast("Figure", plot(study).figure)  # Optuna's matplotlib plots draw on a Figure
            except (RuntimeError, ValueError) as err:  # e.g. importances of values that never vary
                log.warning("no %s figure: %s", name, err)
                continue
            fig.tight_layout()
            try:
                save_figure(fig, out_dir / f"{name}.png")
            finally:
                plt.close(fig)


def load_study(storage: str, study_name: str) -> optuna.Study:
    """The stored study ``study_name``; one that is not there is one line naming those that are."""
    store = check_storage(storage)
    names = [s.study_name for s in store.get_all_studies()]
    if study_name not in names:
        raise ConfigError(f"study={study_name!r} is not in {storage}; allowed: {', '.join(names) or 'none stored'}")
    return optuna.load_study(study_name=study_name, storage=store)
