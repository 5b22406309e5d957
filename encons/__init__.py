"""encons: physics-structured neural networks that learn dynamics from trajectories.

The public surface (``encons.entry.api``), imported on first use so ``import encons`` stays light::

    cfg = encons.compose("model=hnn_angle", "system=pendulum1")   # overrides as on the CLI
    data, module = encons.build(cfg)   # the objects, without training (a notebook)
    run = encons.train(cfg)        # Run: .module (best checkpoint), .metrics, .run_dir
    run = encons.load(run_dir)     # a run folder or a .ckpt (checkpoints carry their config)
    encons.evaluate(run)           # test metrics, figures under <run>/evaluation
    encons.rollout(run.model, start, t, run.module.integrator)
    encons.score_control(run)      # swing-up controller from the model, scored beside the oracle
"""

from importlib import metadata

__all__ = ["Ensemble", "Run", "build", "catalogue", "compose", "evaluate", "load", "rollout", "score_control", "train"]

try:
    __version__ = metadata.version("encons")
except metadata.PackageNotFoundError:  # a source tree that is not installed
    __version__ = "0+unknown"


def __getattr__(name: str):
    if name == "score_control":
        from encons.tools.control import score_control

        return score_control
    if name in __all__:
        from encons.entry import api

        return getattr(api, name)
    raise AttributeError(f"module 'encons' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
