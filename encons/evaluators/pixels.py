"""Scores of rollouts seen through an observation model: decoded frames against the true frames."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from matplotlib.figure import Figure
from torch import Tensor

from encons.evaluators import figures
from encons.evaluators.base import Evaluator, Result, TestBatch, gathered
from encons.infra.errors import ConfigError
from encons.numerics import metrics

if TYPE_CHECKING:
    from encons.numerics.learner import Learner

log = logging.getLogger(__name__)


class Pixels(Evaluator):
    """Test rollouts of a run on frames (an autoencoder, ``encons.models.observation``), decoded and
    compared with the true frames: ``traj_rel_err`` (and its std over videos) of the flattened frames,
    ``pixel_mse`` (over pixels, steps and videos), its value at the last step (mean, median) and the
    fraction of rollouts with a non-finite frame (``diverged``); curves: pixel MSE and relative error per
    video and step, the latent rollouts and the encoder's latents of the true frames (Lim & Kasim §6).
    Beside them, the same pixel MSEs of two references: ``baseline_constant/`` holds each video's first
    frame (a pendulum that never moves) and ``autoencoder/`` decodes the encoder's latents of the true frames
    (the floor the autoencoder sets: what a latent rollout equal to the encoded states scores; every frame but
    the last ``stack`` − 1, which begin no encoder input).
    Runs through an observation model only; no oracle (the frames have no true latent field)."""

    headline = (  # the benchmark summary's headline columns (encons.tools.report)
        "diverged",
        "traj_rel_err",
        "pixel_mse",
        "pixel_mse_final",
        "pixel_mse_final_median",
        "baseline_constant/pixel_mse",
        "autoencoder/pixel_mse",
        "autoencoder/pixel_mse_final",
    )

    def check(self, module: Learner) -> None:
        if module.observation.identity:
            raise ConfigError(
                "evaluators.pixels does not apply to a run without an observation model (no "
                "frames to decode); allowed: evaluators=[states]"
            )

    def reset(self) -> None:
        self.batches: list[tuple[Tensor, ...]] = []

    def update(self, module: Learner, batch: TestBatch) -> None:
        self.batches.append(tuple(p.detach() for p in (batch.x, batch.states, batch.pred.to(batch.states.dtype))))

    def compute(self, module: Learner) -> Result:
        x, states, pred = gathered(module, self.batches)
        self.batches.clear()
        frames = module.observation.decode(pred).double()
        x = x.double()

        def per_frame(a: Tensor, b: Tensor) -> Tensor:  # (N, T)
            return (a - b).square().mean((-1, -2))

        mse = per_frame(frames, x)
        still = per_frame(x[:, :1], x)
        floor = per_frame(module.observation.decode(states).double(), x[:, : states.shape[1]])
        t = module.times(x.shape[1], x).cpu()
        tre = metrics.trajectory_relative_error(frames.flatten(2), x.flatten(2), module.horizon)
        finite = mse.isfinite().all(-1)
        scores = {
            "traj_rel_err": tre.mean().item(),
            "traj_rel_err_std": tre.std().item(),
            "pixel_mse": mse.mean().item(),
            "pixel_mse_final": mse[:, -1].mean().item(),
            "pixel_mse_final_median": mse[:, -1].median().item(),
            "diverged": 1.0 - finite.double().mean().item(),
        }
        for name, ref in (("baseline_constant", still), ("autoencoder", floor)):
            scores |= {f"{name}/pixel_mse": ref.mean().item(), f"{name}/pixel_mse_final": ref[:, -1].mean().item()}
        log.info(
            "pixel MSE of predicted frames: %s",
            ", ".join(
                f"t={t[k]:.0f}: {mse[:, k].mean().item():.4g}"
                for k in sorted({0, len(t) // 4, len(t) // 2, len(t) - 1})
            ),
        )
        curves = {
            "t": t.numpy(),
            "pixel_mse": mse.cpu().numpy(),
            "baseline_constant/pixel_mse": still.cpu().numpy(),
            "autoencoder/pixel_mse": floor.cpu().numpy(),
            "rel_err": metrics.relative_error(frames.flatten(2), x.flatten(2)).cpu().numpy(),
            "latent_pred": pred.cpu().numpy(),
            "latent_encoded": states.cpu().numpy(),
        }
        self.drawn = t, mse.cpu(), still.cpu(), floor.cpu(), pred.cpu(), states.cpu(), frames.cpu(), x.cpu()
        return Result(scores, curves)

    def figures(self, module: Learner) -> dict[str, Figure]:
        """``pixel_mse`` against time, ``latent_phase`` (Lim & Kasim Fig. 4) and ``frames`` (Figs. 5–6)."""
        t, mse, still, floor, pred, states, frames, x = self.drawn
        title = module.run_title()
        references = {"first frame held": still, "autoencoder floor": floor}
        return {
            **figures.pixel_mse_figure(t, mse, title, references),
            **figures.latent_phase_figure(pred, states, title),
            **figures.frames_figure(t, frames, x, title),
        }
