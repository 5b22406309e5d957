"""The one validation pass of a composed config, run before anything is built: one clear error per problem.

:func:`validate` runs every check once (no key left ``???``, every target trusted and looked up once,
the bounds of every node, the model's capabilities, the objective) and returns a :class:`Checked` value
that ``encons.training.build`` instantiates without checking again. It neither rewrites the config (presets are
applied when it is composed, :func:`apply_presets`) nor creates folders (the run does,
``encons.training.build.make_folders``). What the user asked for travels in a :class:`Request`.
"""

from __future__ import annotations

import inspect
import weakref
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from omegaconf import DictConfig, OmegaConf, open_dict

from encons.config import trust
from encons.infra import bounds
from encons.infra.errors import ConfigError

if TYPE_CHECKING:
    from encons.models.base import DynamicsModel
    from encons.models.observation import Observation
    from encons.systems.base import System


@dataclass(frozen=True)
class Request:
    """What the user asked for: Hydra's group choices (``model=symo``) and the command-line overrides;
    both empty for a config read back from a checkpoint."""

    choices: Mapping[str, str] = field(default_factory=dict)
    overrides: tuple[str, ...] = ()

    @classmethod
    def of(cls, cfg: DictConfig) -> Request:
        """The request a composed config carries in its ``hydra`` node (empty without one)."""
        hydra = cfg.get("hydra") if isinstance(cfg, DictConfig) else None
        if hydra is None:
            return cls()
        picked = cast("dict[str, Any]", OmegaConf.to_container(hydra.runtime.choices))  # a DictConfig's: a dict
        choices = {k: v for k, v in picked.items() if isinstance(v, str)}
        return cls(choices, tuple(hydra.overrides.task))

    def overridden(self) -> set[str]:
        """The keys the overrides set (``+``/``~`` stripped)."""
        return {o.split("=", 1)[0].lstrip("+~") for o in self.overrides}


@dataclass(frozen=True)
class Checked:
    """A config that passed :func:`validate`: a read-only copy of it (``cfg``), its resolved run config
    without Hydra's node (``resolved``: what a run is rebuilt from), the ``request``, the trust list it
    was checked against (``trusted``: Hydra's execution whitelist where it is built), every ``_target_``
    string's object (``targets``), the model's class and the run's objective."""

    cfg: DictConfig
    resolved: DictConfig
    request: Request
    trusted: tuple[str, ...]
    targets: Mapping[str, Any]
    model: type
    objective: str

    def derived(self, cfg: DictConfig) -> Checked:
        """The same checked run with ``cfg``, a copy of this one's config that a policy changed within its
        checked bounds (``encons.training.attempts``: ``model.guard=0``, ``ckpt_path=null``); not checked again."""
        return Checked(
            _frozen(cfg), run_config(cfg), self.request, self.trusted, self.targets, self.model, self.objective
        )


def run_config(cfg: DictConfig) -> DictConfig:
    """The resolved run config without Hydra's own node: what a run is rebuilt from."""
    keys: list[Any] = [k for k in cfg if k != "hydra"]
    return cast(DictConfig, OmegaConf.create(OmegaConf.to_container(OmegaConf.masked_copy(cfg, keys), resolve=True)))


def _frozen(cfg: DictConfig) -> DictConfig:
    copy = cfg.copy()
    OmegaConf.set_readonly(copy, True)
    return copy


#: The nodes :func:`validate` checks by the declarations of their target (and ``encons.infra.bounds.DECLARED``).
NODES = (
    "system",
    "model",
    "regulariser",
    "observation",
    "optimizer",
    "scheduler",
    "integrator",
    "evaluation",
    "trainer",
)
#: The groups whose every entry is a node built by its target.
GROUPS = ("logger", "callbacks", "evaluators")


def validate(cfg: DictConfig, request: Request | None = None) -> Checked:
    """Every check of a composed config, each once, before anything is built: no key left ``???``, every
    target trusted (on the string, before any import) and looked up once, the types and ranges of every
    node (``encons.infra.bounds``), the model's capabilities and the objective. ``request`` defaults to the one
    ``cfg``'s ``hydra`` node carries."""
    from encons.data.datamodule import TrajectoryDataModule

    request = Request.of(cfg) if request is None else request
    keys: list[Any] = [k for k in cfg if k != "hydra"]
    task = OmegaConf.masked_copy(cfg, keys)
    missing = sorted(
        OmegaConf.missing_keys(task), key=lambda k: not _is_unset(task, k)
    )  # "???" before what refers to it
    if missing:
        raise ConfigError(f"{missing[0]} has no value; allowed: give it one ({missing[0]}=...)")
    if cfg.get("seeds") is not None:
        check_seeds(cfg.seeds)
        check_ensemble(cfg, request)
    resolved = run_config(cfg)
    trusted = trust.trusted_targets()
    targets = trust.check_targets(
        cast(dict, OmegaConf.to_container(resolved)), trusted, _preset_lookups(cfg)
    )  # a DictConfig's container: a dict
    check_node(cfg, "")
    check_node(cfg, "data", TrajectoryDataModule)
    keys = [k for k in NODES if cfg.get(k)]
    keys += [f"{group}.{name}" for group in GROUPS for name in (cfg.get(group) or {})]
    for key in keys:
        check_node(cfg, key, targets=targets)
    if cfg.data.get("n_val") == 0 and str(cfg.optimized_metric).startswith("val/"):
        raise ConfigError(
            f"data.n_val=0 leaves no validation set for optimized_metric={cfg.optimized_metric}; "
            f"allowed: data.n_val >= 1, or optimized_metric=train/loss"
        )
    check_validation(cfg)
    check_ckpt_path(cfg, request)
    model = targets[cfg.model._target_]
    objective = cfg.objective or model.objectives[0]
    observation = cfg.get("observation")
    if isinstance(observation, DictConfig) and "_target_" in observation:
        check_observation(targets[observation._target_], objective)
    check_model(cfg, model, objective, request)
    if cfg.get("seeds") is not None and cfg.get("plain_solve") and has_guard(model):
        raise ConfigError(
            "plain_solve=true retrains a run from scratch when the plain inverse diverges, which "
            "one member of an ensemble cannot do alone; allowed: plain_solve=false with seeds"
        )
    return Checked(_frozen(cfg), resolved, request, trusted, targets, model, objective)


def check_seeds(seeds: Any) -> list[int]:
    """The ``seeds`` list (a seed ensemble's, a benchmark's), refused in one line unless it is a non-empty
    list of distinct integer seeds."""
    values = list(seeds) if isinstance(seeds, (list, tuple)) or OmegaConf.is_list(seeds) else None
    if (
        not values
        or not all(isinstance(s, int) and not isinstance(s, bool) and 0 <= s < 2**32 for s in values)
        or len(set(values)) != len(values)
    ):
        raise ConfigError(
            f"seeds={seeds}; allowed: a non-empty list of distinct integer seeds in 0..2**32-1, e.g. seeds=[0,1,2]"
        )
    return values


def check_ensemble(cfg: DictConfig, request: Request) -> None:
    """Refuse, in one line each, what a seed ensemble (``seeds``, ``encons.training.ensemble``) cannot be:
    data that differ per seed, DDP, an explicit ``seed`` beside ``seeds`` (and, once the model is known,
    the plain-inverse retry: :func:`validate`)."""
    if "seed" in request.overridden():
        raise ConfigError(
            f"seed={cfg.seed} beside seeds={list(cfg.seeds)}: the members' seeds are the list; "
            f"allowed: one of seed=K or seeds=[...]"
        )
    devices, strategy = cfg.trainer.get("devices", 1), str(cfg.trainer.get("strategy", "auto"))
    if (isinstance(devices, int) and devices > 1) or devices in ("auto", -1) or "ddp" in strategy:
        raise ConfigError(
            f"trainer.devices={devices} trainer.strategy={strategy} with seeds: an ensemble trains "
            f"its members in one process on one device; allowed: trainer.devices=1 (no DDP) with seeds"
        )
    if "${seed" in str(OmegaConf.to_yaml(OmegaConf.masked_copy(cfg, ["data"]), resolve=False)):
        raise ConfigError(
            "data.seed follows seed, so each member would train on other data; allowed: a fixed "
            "data.seed with seeds (the members share their batches)"
        )


def has_guard(cls: type) -> bool:
    """Whether model class ``cls`` solves for q̈ by ``guarded_solve``: its constructor takes ``guard: Guard``
    (the plain-inverse retry of ``plain_solve``, ``encons.training.attempts``)."""
    from encons.models.lnn import Guard

    return bounds.hints(cls).get("guard") == Guard


def check_ckpt_path(cfg: DictConfig, request: Request) -> None:
    """A ``ckpt_path`` file read once before any data are simulated, so that a wrong one (a text file, a
    missing path) is the run's one line, not the last of the data's log lines. Only for a run to train (a
    composed config: its request has group choices); a saved run's config keeps the ckpt_path it resumed from."""
    from encons.infra import checkpoints

    path = cfg.get("ckpt_path")
    if path is None or path == "last" or not request.choices:
        return
    if not Path(str(path)).is_file():
        raise ConfigError(f"ckpt_path={str(path)!r} does not exist; allowed: a .ckpt file, last or null")
    checkpoints.read(str(path), "ckpt_path")


#: validation.criterion values (encons.training.module.TrainingModule.validation_step; none: no validation loop).
CRITERIA = ("rollout", "objective", "none")


def check_validation(cfg: DictConfig) -> None:
    """``validation.every`` an integer >= 1 and ``validation.criterion`` one of ``CRITERIA``, and every
    metric the run monitors (the best checkpoint's ``optimized_metric``, a plateau schedule's val/loss)
    one that the criterion logs."""
    every, criterion = cfg.validation.every, cfg.validation.criterion
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise ConfigError(f"validation.every={every}; allowed: an integer >= 1 (epochs between validations)")
    if criterion not in CRITERIA:
        raise ConfigError(f"validation.criterion={criterion}; allowed: {', '.join(CRITERIA)}")
    monitors = [
        cb.monitor
        for cb in (cfg.get("callbacks") or {}).values()
        if isinstance(cb, DictConfig) and str(cb.get("monitor") or "").startswith("val/")
    ]
    if "plateau" in str((cfg.get("scheduler") or {}).get("_target_", "")).lower():
        monitors.append("val/loss")
    logged = {"rollout": ("val/loss", "val/traj_rel_err"), "objective": ("val/loss",), "none": ()}[criterion]
    if missed := [m for m in monitors if m not in logged]:
        raise ConfigError(
            f"validation.criterion={criterion} logs no {missed[0]}, which this run monitors "
            f"(optimized_metric or scheduler=plateau); allowed: "
            + (
                f"optimized_metric={' or '.join(logged)}"
                if logged
                else "validation.criterion=rollout or objective, or no monitor (~callbacks.best, scheduler=none)"
            )
        )


def _is_unset(cfg: DictConfig, key: str) -> bool:
    """Whether ``key`` itself is ``???`` (not an interpolation of a key that is)."""
    parent, _, leaf = key.rpartition(".")
    return OmegaConf.is_missing(OmegaConf.select(cfg, parent) if parent else cfg, leaf)


def check_node(cfg: DictConfig, key: str, target: Any = None, targets: Mapping[str, Any] | None = None) -> None:
    """Check the values of node ``cfg[key]`` (``""``: the top level) against the declarations of its
    ``_target_``'s constructor (or ``target``'s; ``targets`` maps target strings already looked up to
    their objects) and those of the functions that read it (``encons.infra.bounds.DECLARED``), by
    ``encons.infra.bounds.check``."""
    node = OmegaConf.select(cfg, key) if key else cfg
    if not isinstance(node, DictConfig):
        return
    declared = dict(bounds.DECLARED.get(key, {}))
    if key:
        values = cast("dict[str, Any]", OmegaConf.to_container(node, resolve=True))  # a DictConfig's: a dict
        name = values.get("_target_")
        if target is None and isinstance(name, str):
            target = targets[name] if targets is not None and name in targets else trust.locate(name, key)
        declared = {**(bounds.hints(target) if target is not None else {}), **declared}
    else:
        values = {k: node.get(k) for k in declared if k in node}
    bounds.check({k: v for k, v in values.items() if not k.startswith("_")}, declared, key)
    if key and target is not None:
        bounds.check_rules(target, {k: v for k, v in values.items() if not k.startswith("_")}, key)


def apply_presets(cfg: DictConfig, request: Request) -> None:
    """Drop the keys a preset set for any model (``preset_keys``, e.g. ``debug=fast``'s ``model.hidden``)
    from a node whose ``_target_``'s constructor does not take them; a key also set on the command line stays
    (and is refused where the node is built). ``preset_keys`` maps each group that sets presets to its keys
    (``{debug: [model.hidden, model.depth]}``), so that the groups' mappings merge where lists would
    replace each other (``experiment=paper debug=fast``); a list is one group's (a config saved before)."""
    presets = cfg.get("preset_keys") or {}
    located: dict[str, Any] = {}  # node key -> its target, each looked up once
    for full in dict.fromkeys(
        k for keys in (presets.values() if isinstance(presets, DictConfig) else [presets]) for k in keys or ()
    ):
        node_key, _, name = str(full).rpartition(".")
        node = OmegaConf.select(cfg, node_key)
        if isinstance(node, DictConfig) and name in node and node_key not in located:
            located[node_key] = trust.locate(str(node.get("_target_", "")), node_key)
        target = located.get(node_key) if isinstance(node, DictConfig) and name in node else None
        if target is None or full in request.overridden():
            continue
        params = inspect.signature(target).parameters
        if name not in params and not any(p.kind is p.VAR_KEYWORD for p in params.values()):
            with open_dict(node):
                del node[name]
    _hand_over(cfg, {str(OmegaConf.select(cfg, f"{k}._target_")): t for k, t in located.items() if t is not None})


#: What :func:`apply_presets` looked up, by the config object it ran on (its id, while that object lives):
#: :func:`validate` of the same config starts from it, so that a composed run looks each target up once
#: from compose to build. Only a target string's object is kept: a key changed since names another string.
_PRESET_LOOKUPS: dict[int, tuple[weakref.ref, dict[str, Any]]] = {}


def _hand_over(cfg: DictConfig, located: dict[str, Any]) -> None:
    key = id(cfg)
    _PRESET_LOOKUPS[key] = (weakref.ref(cfg, lambda _: _PRESET_LOOKUPS.pop(key, None)), located)


def _preset_lookups(cfg: DictConfig) -> dict[str, Any]:
    ref, located = _PRESET_LOOKUPS.get(id(cfg), (None, {}))
    return dict(located) if ref is not None and ref() is cfg else {}


def objective_of(cfg: DictConfig) -> str:
    """The run's objective: ``cfg.objective``, or when null the model's default (its first)."""
    return cfg.objective or trust.locate(cfg.model._target_, "model").objectives[0]


def check_observation(cls: type[Observation], objective: str) -> None:
    """Refuse an objective the observation model (class ``cls``, ``encons.models.observation``) cannot train."""
    if cls.objectives is not None and objective not in cls.objectives:
        raise ConfigError(
            f"objective={objective} does not apply to observation={cls.__name__.lower()} (no true "
            f"latent derivatives); allowed: {', '.join(cls.objectives)}"
        )


def check_model(cfg: DictConfig, cls: type[DynamicsModel], objective: str, request: Request) -> None:
    """Refuse an objective × compile × regulariser × integrator override model class ``cls`` does not support
    (its class attributes, ``encons.models.base``); ``request`` names the model as the user chose it and
    says whether the user overrode the integrator."""
    name = request.choices.get("model") or cls.__name__
    if objective not in cls.objectives:
        raise ConfigError(f"objective={objective} does not apply to model={name}; allowed: {', '.join(cls.objectives)}")
    if cfg.get("compile") and (cls.discrete or cfg.get("regulariser")):
        reason = (
            f"model={name} is discrete (no field)"
            if cls.discrete
            else "the regularisers take Jacobians of the field by torch.func, which is not tested on a compiled one"
        )
        raise ConfigError(f"compile=true compiles the model's vector field, and {reason}; allowed: compile=false")
    if cfg.get("regulariser") and cls.discrete:
        raise ConfigError(
            f"regulariser={cfg.regulariser._target_.rsplit('.', 1)[-1].lower()} needs a vector field "
            f"and model={name} is discrete (it steps itself); allowed: regulariser=none"
        )
    if cls.discrete:
        overridden = [o for o in request.overrides if o.lstrip("+~").startswith("integrator")]
        if overridden:
            raise ConfigError(
                f"{overridden[0]} does not apply to model={name}: a discrete model advances by its "
                f"own step; allowed: no integrator override"
            )


def check_fit(cfg: DictConfig, cls: type[DynamicsModel], system: System, request: Request) -> None:
    """Refuse a model class ``cls`` the built (latent) ``system`` cannot serve: its chart, holonomic
    constraints, control inputs (the one check that needs the system object, made where it is built)."""
    name = request.choices.get("model") or cls.__name__
    chart = cfg.model.get("chart") or getattr(cls, "default_chart", None) or system.base_chart
    if chart not in system.charts:
        raise ConfigError(
            f"model {cls.__name__} needs the '{chart}' chart, which system '{system.name}' "
            f"lacks; allowed: a model for its charts {list(system.charts)}"
        )
    if getattr(cls, "needs_constraints", False) and system.layout is None:
        raise ConfigError(
            f"model {cls.__name__} needs holonomic constraints, which system '{system.name}' "
            f"does not declare; allowed: a model in generalised coordinates"
        )
    if system.n_controls and not cls.supports_controls:
        raise ConfigError(
            f"model={name} cannot take control inputs, and system '{system.name}' has "
            f"{system.n_controls}; allowed: a model that supports controls (e.g. node, lnode, symo)"
        )


def check_capabilities(cfg: DictConfig, cls: type[DynamicsModel], system: System, request: Request) -> None:
    """:func:`check_fit` and :func:`check_model` of a config that did not pass :func:`validate`."""
    check_fit(cfg, cls, system, request)
    check_model(cfg, cls, objective_of(cfg), request)
