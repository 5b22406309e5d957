"""The observation seam: how a run's data enter and leave its dynamics model.

A dynamics model (``encons.models.base``) works on states s (..., 2n) with its own ``encode`` /
``decode`` to internal coordinates. An ``Observation`` sits outside it: ``encode`` maps what the
data hold (batch entry ``key``) to those states and ``decode`` maps states back to observations.
``Observation`` itself is the identity on the system's states (``observation=none``, every run
before pixels); ``Autoencoder`` (``observation=autoencoder``) maps frames to a latent state of
``latent`` numbers, and the dynamics model is built on ``LatentSystem`` of that size, so any model
of generalised coordinates (``node``, ``hnn``, ``nsf``, ...) learns the latent dynamics and the
Lim & Kasim regularisers act on the latent field (``TrainingModule`` passes them encoded states).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, ClassVar

import torch
from torch import Tensor, nn

from encons.infra.bounds import Count, Declared, NonNegative, Range
from encons.infra.errors import ConfigError, DataError
from encons.models.networks import ACTIVATIONS, mlp
from encons.systems.base import System
from encons.systems.latent import LatentSystem


class Observation(nn.Module, Declared):
    """The identity: the model sees the system's states (batch entry ``states``)."""

    config_key = "observation"
    key: ClassVar[str] = "states"
    identity: ClassVar[bool] = True
    objectives: ClassVar[tuple[str, ...] | None] = None  # None: every objective the model supports

    def latent_system(self, system: System) -> System:
        """The system the dynamics model is built on."""
        return system

    def data_chart(self, system: System, model_chart: str) -> str:
        """The chart the data module serves states in."""
        return model_chart

    def encode(self, x: Tensor) -> Tensor:
        """Observations (B, T, ...) -> states (B, T - window + 1, 2n)."""
        return x

    def decode(self, s: Tensor) -> Tensor:
        """States (..., 2n) -> observations (..., *shape of one observation)."""
        return s

    def loss(self, x: Tensor, s: Tensor, pred: Tensor, reduce: Callable[[Tensor], Tensor] = torch.mean) -> Tensor:
        """Terms added to the rollout objective, given observations ``x`` (B, T, ...), their encoded
        states ``s`` and the rolled-out states ``pred`` (B, T, 2n), one per window, meaned over the windows by
        ``reduce`` (a stacked ensemble's means each member's, ``encons.training.stacked``). Zero for the identity."""
        return x.new_zeros(())

    def check_data(self, arrays: dict[str, Tensor], source: str, window: int) -> None:
        """Refuse data without what this observation model reads (training windows of ``window`` steps)."""


class FrameRange(nn.Module):
    """Clamp to the frames' range [0, 1] with the identity's gradient (straight-through): values are
    bounded, while a pixel clamped on the wrong side of its target still gets the gradient a linear output
    would (a plain clamp stops it: measured, the autoencoder's fit 3× worse after 300 steps)."""

    def forward(self, x: Tensor) -> Tensor:
        return x + (x.clamp(0.0, 1.0) - x).detach()


class Autoencoder(Observation):
    """MLP autoencoder of grey-scale frames around a latent dynamics model (Greydanus et al. 2019, §3
    "pixel pendulum"; Lim & Kasim 2023, §6).

    Encoder: ``stack`` consecutive frames X_t = (x_t, …, x_{t+stack−1}) (Greydanus et al. stack two),
    flattened, through ``depth`` hidden layers of ``hidden`` units (ReLU: Lim & Kasim §6 found it
    better for the autoencoder) to ``latent`` numbers z_t, the state at time t. Decoder: the mirror
    MLP from z_t back to all ``stack`` frames, as Greydanus et al.'s autoencoder reconstructs its whole
    input — so z_t must hold the motion between the frames, not only the pose (decoding the first
    frame alone lets the latent collapse onto a curve of poses, measured); ``decode`` gives the first,
    the frame at time t. Loss beside the module's rollout objective on the latent states (L1 of
    ẑ_t − z_t summed over the window, Zhong et al. §4.1; the latent dynamics term of Greydanus et al.),
    per window of T frames:

        weight_reconstruction × mean_t Σ_{stack, pixels} (dec(z_t) − X_t)²   (autoencoder, Greydanus' L_AE)
      + weight_prediction     × mean_t Σ_pixels (decode(ẑ_t) − x_t)²       (predicted frames, t < T)
      + weight_velocity       × mean_t Σ_i (p_{t,i} − (q_{t+1,i} − q_{t,i}))²  (Greydanus' auxiliary loss)

    with ẑ the latent rollout from z_0 over the window and z = (q, p) split in halves. The last term
    is Greydanus et al.'s: it makes the second half of the latent the per-frame change of the first,
    so that the latent holds the motion; without it the encoder keeps the pose only (the velocity
    changes a frame little) and the latent collapses onto a curve of poses (measured: NODE then
    learns a sink). Only the rollout objective applies: there are no true latent derivatives.
    The decoder ends in ``FrameRange``, so every decoded frame lies in [0, 1], the range of the frames
    (float in [0, 1] or uint8 scaled to it): Greydanus et al.'s decoder is linear, and with it a latent
    rollout that leaves the region the encoder covers decoded to pixel values of 1e5 and more, so a few
    videos made the mean pixel MSE 1e10–1e23 (measured on ``profile=pixels``, 1000 epochs).
    Limits: an MLP, so it neither knows nor needs image structure (fine at 28 × 28; no
    convolutional variant).
    """

    key = "obs"
    identity = False
    objectives = ("rollout",)

    def __init__(
        self,
        system: System,
        latent: Annotated[int, Range(ge=2)] = 2,
        stack: Count = 2,
        hidden: Count = 200,
        depth: Count = 2,
        activation: str = "relu",
        frame_shape: list[int] | None = None,
        weight_reconstruction: NonNegative = 1.0,
        weight_prediction: NonNegative = 1.0,
        weight_velocity: NonNegative = 1.0,
    ):
        super().__init__()
        shape = tuple(frame_shape) if frame_shape is not None else system.frame_shape
        if shape is None:
            raise ConfigError(
                f"observation.frame_shape=null and system '{system.name}' renders no frames; allowed: "
                f"a pixel system (pixel_pendulum, pixel_damped_pendulum) or [H, W] of the frames "
                f"(obs_* arrays) in your data file"
            )
        if len(shape) != 2 or min(shape) < 1:
            raise ConfigError(f"observation.frame_shape={list(shape)}; allowed: [H, W], two positive integers")
        if activation not in ACTIVATIONS:
            raise ConfigError(
                f"observation.activation={activation!r} is unknown; allowed: {', '.join(sorted(ACTIVATIONS))}"
            )
        self.system = LatentSystem(latent, system)
        self.frame_shape, self.stack = shape, stack
        self.weights = (float(weight_reconstruction), float(weight_prediction), float(weight_velocity))
        pixels = shape[0] * shape[1]
        self.encoder = mlp(stack * pixels, latent, hidden, depth, activation)
        self.decoder = nn.Sequential(mlp(latent, stack * pixels, hidden, depth, activation), FrameRange())

    def latent_system(self, system: System) -> System:
        return self.system

    def data_chart(self, system: System, model_chart: str) -> str:
        return system.base_chart  # the states only score; the model sees frames

    def stacks(self, x: Tensor) -> Tensor:
        """Encoder inputs X_t of frames x (B, T, H, W): (B, T - stack + 1, stack, H, W)."""
        return x.unfold(1, self.stack, 1).movedim(-1, -3)

    def encode(self, x: Tensor) -> Tensor:
        return self.encoder(self.stacks(x).flatten(-3))

    def decode_stack(self, s: Tensor) -> Tensor:
        """The ``stack`` frames (..., stack, H, W) from time t on of states z_t (..., latent)."""
        return self.decoder(s).unflatten(-1, (self.stack, *self.frame_shape))

    def decode(self, s: Tensor) -> Tensor:
        return self.decode_stack(s)[..., 0, :, :]

    def loss(self, x: Tensor, s: Tensor, pred: Tensor, reduce: Callable[[Tensor], Tensor] = torch.mean) -> Tensor:
        w_rec, w_pred, w_vel = self.weights
        rec = (self.decode_stack(s) - self.stacks(x)).square().sum((-1, -2, -3)).mean(-1)
        predicted = (self.decode(pred) - x).square().sum((-1, -2)).mean(-1)
        q, p = s.chunk(2, -1)
        velocity = (p[:, :-1] - q.diff(dim=1)).square().sum(-1).mean(-1) if s.shape[1] > 1 else 0.0
        return reduce(w_rec * rec + w_pred * predicted + w_vel * velocity)

    def check_data(self, arrays: dict[str, Tensor], source: str, window: int) -> None:
        frames = arrays.get(self.key)
        if frames is None:
            raise DataError(
                f"observation=autoencoder needs frames and {source} holds none; allowed: a pixel system "
                f"(pixel_pendulum, pixel_damped_pendulum) or a data file with obs_train, obs_test (N, T, H, W)"
            )
        if tuple(frames.shape[-2:]) != self.frame_shape:
            raise DataError(
                f"{source}: frames are {tuple(frames.shape[-2:])} pixels; allowed: observation.frame_shape="
                f"{list(self.frame_shape)} (set it to the file's H, W)"
            )
        if window < self.stack:
            raise ConfigError(
                f"data.chunk_len={window} is shorter than observation.stack={self.stack}; allowed: "
                f"data.chunk_len >= {self.stack} (a window must hold one encoder input)"
            )
