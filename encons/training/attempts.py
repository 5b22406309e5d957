"""A run's attempts at training: one, or under ``plain_solve=true`` (``experiment=paper``) the paper's plain
inverse first and the model's guarded solve only if that diverges.

A model whose constructor takes ``guard: Guard`` (``encons.models.lnn.guarded_solve``: ``lnn``, ``lnn_angle``,
``glnn``) then trains first at ``model.guard=0``: the plain (∇²_q̇L)⁻¹ of Cranmer et al. (Zhong et al. eq. 3)
and Xiao et al. eq. (11). If that training diverges (``DivergenceError``: a non-finite loss, e.g. at a
singular ∇²_q̇L), its files are moved to ``<run>/diverged_plain/`` (nothing is deleted; the log stays) and the
run trains again from scratch, same seed, at the configured ``model.guard``. ``plain_inverse`` in the test
metrics (1: the plain inverse, 0: the guarded solve) and the run's summary say which solve gave the result;
``config.yaml`` holds the ``model.guard`` it trained with. Every other model trains once, unchanged.
A resume (``ckpt_path``) continues the attempt its checkpoint trained. Limits: only a divergence in training
switches (test rollouts that diverge are the model's result, ``diverged``); the plain attempt's time counts in
``wall_time_s``; under DDP every process would move the files (untested).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from omegaconf import DictConfig

from encons.config import trust
from encons.config.check import has_guard
from encons.infra import checkpoints
from encons.infra.bounds import declare
from encons.infra.errors import ConfigError

if TYPE_CHECKING:
    from encons.config.check import Request

#: Where a diverged plain-inverse attempt's files go, inside the run folder.
SET_ASIDE = "diverged_plain"


@dataclass(frozen=True)
class Attempt:
    """One training of a run: its config and request; ``plain`` (True: the plain inverse, False: the guarded
    solve, None: one attempt without a choice of solve) and, for the guarded solve, ``why`` it is used."""

    cfg: DictConfig
    request: Request
    plain: bool | None = None
    why: str = ""

    def describe(self) -> str:
        """The summary's line on the solve (empty without a choice of solve)."""
        if self.plain is None:
            return ""
        return "solve: " + (
            "the plain inverse (model.guard=0)"
            if self.plain
            else f"guarded (model.guard={self.cfg.model.guard:g}): {self.why}"
        )


@declare("", plain_solve=bool)
def plan(cfg: DictConfig, request: Request, model: type | None = None) -> list[Attempt]:
    """The attempts of a checked config (its model target trusted; ``model``: its class, if looked up
    already), in order: the plain inverse, then the guarded solve from scratch (no ``ckpt_path``); or one:
    a model without a guard, no ``plain_solve``, ``model.guard=0``, or a resume (``ckpt_path``) of a
    checkpoint trained with the guarded solve."""
    if not cfg.get("plain_solve"):
        return [Attempt(cfg, request)]
    model = trust.locate(cfg.model._target_, "model") if model is None else model
    if not has_guard(model):
        return [Attempt(cfg, request)]
    if cfg.model.guard == 0:
        return [Attempt(cfg, request, plain=True)]
    plain, guarded = copy.deepcopy(cfg), copy.deepcopy(cfg)
    plain.model.guard = 0.0
    if cfg.ckpt_path is not None and _resumes_guarded(plain, guarded):
        return [Attempt(guarded, request, plain=False, why="resumed from a checkpoint trained with it")]
    guarded.ckpt_path = None
    return [Attempt(plain, request, plain=True), Attempt(guarded, request, plain=False)]


def _resumes_guarded(plain: DictConfig, guarded: DictConfig) -> bool:
    """Whether the run's ``ckpt_path`` continues a guarded attempt: its checkpoint trained at model.guard ≠ 0;
    for ``last``, an earlier run has the guarded config and none the plain one (none at all: False, and
    the plain attempt says why nothing resumes)."""
    if plain.ckpt_path != "last":
        path = checkpoints.resume_from(plain)
        assert path is not None  # the caller's ckpt_path is set, and not last: that path
        saved = checkpoints.stored_config(path)
        return bool((saved.get("model") or {}).get("guard"))
    for cfg in (plain, guarded):
        try:
            checkpoints.resume_from(cfg)
        except ConfigError:
            continue
        return cfg is guarded
    return False


def record(cfg: DictConfig, model: type) -> dict[str, float]:
    """What a test reports of the solve under ``plain_solve`` for model class ``model`` built from ``cfg``:
    ``plain_inverse`` 1 (``model.guard`` 0) or 0 (guarded); nothing for a model without a guard or a run
    without ``plain_solve``. The run (``encons.training.runs``) passes it down to ``encons.training.build.build``."""
    if not cfg.get("plain_solve") or not has_guard(model):
        return {}
    return {"plain_inverse": float(cfg.model.guard == 0)}


def set_aside(run_dir: Path) -> Path:
    """Move what a diverged attempt wrote in ``run_dir`` (checkpoints, config, figures, loggers' folders)
    into a new ``diverged_plain`` folder there (``diverged_plain_2``, ... if taken); Hydra's ``.hydra``, the
    log files and earlier set-aside folders stay."""
    aside = run_dir / SET_ASIDE
    k = 1
    while aside.exists():
        k += 1
        aside = run_dir / f"{SET_ASIDE}_{k}"
    aside.mkdir()
    for entry in sorted(run_dir.iterdir()):
        if entry.name != ".hydra" and entry.suffix != ".log" and not entry.name.startswith(SET_ASIDE):
            entry.rename(aside / entry.name)
    return aside
