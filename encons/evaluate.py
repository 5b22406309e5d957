"""Roll out a trained run's checkpoint on a test set: metrics, figures, summary table.

    python -m encons.evaluate RUN_DIR [ckpt=best|last|PATH] [key=value ...]

``RUN_DIR`` is a training run's output folder (it holds ``config.yaml`` and ``checkpoints/``).
Overrides change the evaluation, e.g. ``data.test_steps=1000`` for a long horizon or
``data.n_test=500``; results land in ``RUN_DIR/evaluation/``.
"""

from __future__ import annotations

import sys
from pathlib import Path

from omegaconf import OmegaConf

from encons.errors import ConfigError, EnconsError
from encons.report import print_summary


def find_checkpoint(run_dir: Path, which: str) -> str:
    """``best`` (lowest validation error), ``last``, or a path to a ``.ckpt``."""
    if which == "last":
        found = [run_dir / "checkpoints" / "last.ckpt"]
    elif which == "best":
        found = sorted((run_dir / "checkpoints").glob("best-*.ckpt"))
    else:
        found = [Path(which)]
    if not found or not found[-1].is_file():
        raise ConfigError(f"ckpt={which!r}: no such checkpoint under {run_dir}; use best, last or a .ckpt path")
    return str(found[-1])


def evaluate(run_dir: str | Path, overrides: list[str] = ()) -> dict[str, float]:
    """Test the checkpoint of ``run_dir`` with its own config plus ``overrides``; return the metrics."""
    from encons.train import build, build_trainer

    run_dir = Path(run_dir)
    if not (run_dir / "config.yaml").is_file():
        raise ConfigError(f"{str(run_dir)!r} is not a training run folder (no config.yaml)")
    cfg = OmegaConf.merge(OmegaConf.load(run_dir / "config.yaml"), OmegaConf.from_dotlist(list(overrides)))
    ckpt = find_checkpoint(run_dir, str(cfg.pop("ckpt", "best")))
    cfg.paths.output_dir = str(run_dir / "evaluation")
    cfg.logger, cfg.callbacks = None, None
    data, module = build(cfg)
    trainer, _ = build_trainer(cfg)
    trainer.test(module, datamodule=data, ckpt_path=ckpt, verbose=False)
    results = {f"test/{k}": v for k, v in module.test_metrics.items()}
    print_summary(f"{module.run_title()} — {Path(ckpt).name}", results, Path(cfg.paths.output_dir))
    return results


def main() -> None:
    if len(sys.argv) < 2 or sys.argv[1] in ("-h", "--help"):
        print(__doc__)
        sys.exit(0 if len(sys.argv) > 1 else 2)
    try:
        evaluate(sys.argv[1], sys.argv[2:])
    except EnconsError as err:
        print(f"encons: error: {err}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    main()
