"""``encons-train --help`` lists the groups a user picks from, not internal bases or other tools' groups."""

from __future__ import annotations


def test_help_lists_only_user_facing_groups(cli, tmp_path):
    proc = cli("--help", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    groups = proc.stdout[proc.stdout.index("== Config groups") : proc.stdout.index("== Config (")]
    assert "system: cartpole" in groups and "model: chnn" in groups and "debug: fast" in groups
    assert "sweeps: chnn_tuning" in groups and "with -m" in groups
    assert (
        "optimizer: adamw" in groups
        and "evaluators (a list, default [states]): acceleration, pixels, santos, states" in groups
    )
    for internal in ("_chain", "_base", "profile", "pruner", "paths:", "hydra/"):
        assert internal not in groups, internal
    assert "Warning" not in proc.stderr and not any(tmp_path.iterdir())
