"""A model of one's own: a class in the user's package and its YAML in the user's config folder,
found through ``hydra.searchpath``, trained through the CLI without editing encons."""

from __future__ import annotations

import json
import os
import textwrap

import pytest

from tests.helpers import run_cli

MODEL = '''
"""A linear vector field ż = A z (a test model)."""
import torch
from torch import nn

from encons.models.base import DynamicsModel


class Linear(DynamicsModel):
    def __init__(self, system, chart=None, scale: float = 0.1):
        super().__init__(system, chart)
        self.a = nn.Parameter(scale * torch.eye(2 * self.n))

    def forward(self, t, z, u=None):
        return z @ self.a.T
'''


# debug=fast without its model.hidden/depth (the user's model has neither)
TINY = [
    "logger=none",
    "data.n_train=16",
    "data.n_val=4",
    "data.n_test=4",
    "data.n_steps=10",
    "data.batch_size=8",
    "trainer.max_epochs=2",
]


@pytest.fixture
def user_project(tmp_path):
    """``mypkg/linear.py`` and ``myconf/model/linear.yaml``, outside the encons tree."""
    (tmp_path / "mypkg").mkdir()
    (tmp_path / "mypkg" / "__init__.py").write_text("")
    (tmp_path / "mypkg" / "linear.py").write_text(textwrap.dedent(MODEL))
    (tmp_path / "myconf" / "model").mkdir(parents=True)
    (tmp_path / "myconf" / "model" / "linear.yaml").write_text(
        "# A linear field ż = A z (a user's model)\n_target_: mypkg.linear.Linear\nchart: null\nscale: 0.1\n"
    )
    path = os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")])
    return tmp_path, {"PYTHONPATH": path, "ENCONS_ROOT": str(tmp_path)}


@pytest.mark.slow
def test_user_model_trains_through_the_cli(user_project, cli):
    root, env = user_project
    args = [
        "model=linear",
        "system=pendulum1",
        *TINY,
        f"hydra.searchpath=[file://{root / 'myconf'}]",
        f"hydra.run.dir={root / 'run'}",
    ]
    proc = run_cli(*args, cwd=root, env={**env, "ENCONS_TRUSTED_TARGETS": "mypkg.*"})
    assert proc.returncode == 0, proc.stderr[-2000:]
    metrics = json.loads((root / "run" / "test_metrics.json").read_text())
    assert metrics["traj_rel_err"] > 0
    assert "linear on pendulum1" in proc.stdout

    # refused on the string, before any import: no trust variable, so no run (in this process)
    untrusted = cli(*args[:-1], f"hydra.run.dir={root / 'run2'}", cwd=root)
    assert untrusted.returncode == 2 and "Traceback" not in untrusted.stderr
    assert (
        "encons: error: model._target_='mypkg.linear.Linear' is not a trusted target; allowed: encons.*"
        in untrusted.stderr
    )


def test_a_missing_target_gives_one_line(cli, tmp_path):
    proc = cli("model=node", "model._target_=encons.models.node.Nope", "debug=fast", cwd=tmp_path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and "encons.models.node.Nope" in proc.stderr, proc.stderr


def test_a_benchmarks_searchpath_reaches_every_run(user_project, monkeypatch):
    """Issue 51: `hydra.searchpath=[file://conf]` on the benchmark command must reach its runs (it aborted at the
    first run of the user's model with "model=linear is unknown")."""
    import sys

    from encons.tools import benchmark
    from encons.training.build import compose

    root, _ = user_project
    monkeypatch.syspath_prepend(str(root))
    monkeypatch.setenv("ENCONS_TRUSTED_TARGETS", "mypkg.*")
    monkeypatch.delitem(sys.modules, "mypkg", raising=False)
    cfg = compose(
        [f"hydra.searchpath=[file://{root / 'myconf'}]", "models=[node,linear]", "systems=[pendulum1]"],
        config_name="benchmark",
    )
    runs = benchmark.expand(cfg)
    targets = {compose(r.overrides).model._target_ for r in runs}
    assert {"encons.models.node.NODE", "mypkg.linear.Linear"} <= targets
