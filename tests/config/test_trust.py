"""Nothing a file says runs code: a crafted checkpoint is refused on every route before it is
unpickled, a config file cannot widen the trusted targets, an untrusted module is never imported,
and an alias of a trusted name is refused by encons' own check."""

from __future__ import annotations

import textwrap

import pytest
import torch
from omegaconf import OmegaConf

from encons.entry import api
from encons.entry.api import build
from encons.infra import checkpoints
from encons.infra.errors import ConfigError
from encons.tools import benchmark
from encons.training.build import compose, run_config


class WritesMarker:
    """Unpickling this calls ``open(marker, "w")``: the marker file appears if the pickle runs."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return open, (self.marker, "w")


@pytest.fixture
def evil_ckpt(tmp_path):
    """``(path, marker)``: a checkpoint-shaped file whose pickle would create ``marker``."""

    def plant(path):
        path.parent.mkdir(parents=True, exist_ok=True)
        torch.save({"state_dict": {}, "epoch": 0, "payload": WritesMarker(tmp_path / "pwned")}, path)
        return path

    return plant, tmp_path / "pwned"


def fast(tmp_path, *overrides, out="run"):
    return compose(
        ["debug=fast", "model=node", "system=pendulum1", *overrides], tmp_path / "runs" / out, tmp_path / "cache"
    )


def test_the_one_reader_refuses_a_pickle_that_runs_code(tmp_path, evil_ckpt):
    plant, marker = evil_ckpt
    with pytest.raises(ConfigError, match="is not a readable checkpoint"):
        checkpoints.read(plant(tmp_path / "x.ckpt"))
    assert not marker.exists()


def test_resume_by_path_refuses_it(tmp_path, evil_ckpt):
    plant, marker = evil_ckpt
    path = plant(tmp_path / "evil.ckpt")
    with pytest.raises(ConfigError, match=r"ckpt_path=.*evil.ckpt.* is not a readable checkpoint"):
        api.train(fast(tmp_path, f"ckpt_path={path}"))
    assert not marker.exists()


def test_resume_from_last_refuses_a_planted_sibling(tmp_path, evil_ckpt):
    plant, marker = evil_ckpt
    plant(tmp_path / "runs" / "earlier" / "checkpoints" / "last.ckpt")
    with pytest.raises(ConfigError, match="last.ckpt.* is not a readable checkpoint"):
        checkpoints.resume_from(fast(tmp_path, "ckpt_path=last", out="now"))
    assert not marker.exists()


def test_benchmark_resume_starts_afresh_instead(tmp_path, evil_ckpt, capsys):
    plant, marker = evil_ckpt
    ckpts = tmp_path / "runs" / "run" / "checkpoints"
    plant(ckpts / "last.ckpt")
    cfg = fast(tmp_path)
    benchmark.resume_or_clear(cfg, ckpts)
    assert cfg.ckpt_path is None and not ckpts.exists()
    assert "last.ckpt refused" in capsys.readouterr().out
    assert not marker.exists()


@pytest.mark.parametrize("route", ["evaluate", "load"])
def test_evaluate_and_load_refuse_it(tmp_path, evil_ckpt, route):
    plant, marker = evil_ckpt
    path = plant(tmp_path / "run" / "checkpoints" / "best-epoch0001.ckpt")
    for target in (path, path.parent.parent):
        with pytest.raises(ConfigError, match="is not a readable checkpoint"):
            getattr(api, route)(target)
    assert not marker.exists()


@pytest.fixture
def evil_module(tmp_path, monkeypatch):
    """A module ``evilmod`` on ``sys.path`` that creates a marker file when imported."""
    marker = tmp_path / "imported"
    (tmp_path / "evilmod.py").write_text(
        textwrap.dedent(f"""
        open({str(marker)!r}, "w").close()
        class Model:
            pass
    """)
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    return marker


def test_an_untrusted_target_is_refused_before_its_module_is_imported(tmp_path, evil_module):
    with pytest.raises(ConfigError, match="model._target_='evilmod.Model' is not a trusted target"):
        build(fast(tmp_path, "model._target_=evilmod.Model"))
    assert not evil_module.exists()


def test_a_checkpoints_saved_config_is_checked_before_any_import(tmp_path, evil_module):
    config = OmegaConf.to_container(run_config(fast(tmp_path)))
    config["model"]["_target_"] = "evilmod.Model"
    path = tmp_path / "run" / "checkpoints" / "best-epoch0001.ckpt"
    path.parent.mkdir(parents=True)
    torch.save({"state_dict": {}, "epoch": 0, checkpoints.CONFIG_KEY: config}, path)
    with pytest.raises(ConfigError, match="not a trusted target"):
        api.load(path)
    assert not evil_module.exists()


def test_a_searchpath_config_cannot_widen_trust(tmp_path, evil_module, cli):
    group = tmp_path / "extra" / "widen"
    group.mkdir(parents=True)
    (group / "all.yaml").write_text(
        textwrap.dedent("""
        # @package _global_
        hydra:
          job:
            env_set:
              ENCONS_TRUSTED_TARGETS: evilmod.*
        model:
          _target_: evilmod.Model
    """)
    )
    result = cli(
        "debug=fast",
        "logger=none",
        f"hydra.searchpath=[file://{tmp_path / 'extra'}]",
        "+widen=all",
        f"hydra.run.dir={tmp_path / 'out'}",
        f"paths.cache_dir={tmp_path / 'cache'}",
    )
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert lines[-1].startswith("encons: error: hydra.job.env_set.ENCONS_TRUSTED_TARGETS is set by a config")
    assert "Traceback" not in result.stderr
    assert not evil_module.exists()


@pytest.mark.parametrize(
    "target, why",
    [
        ("encons.config.trust.os.system", "os is a module reached by attribute"),
        ("encons.training.build.Path", "not encons's"),
    ],
)
def test_an_alias_of_a_trusted_name_is_refused(tmp_path, target, why):
    with pytest.raises(ConfigError) as err:
        build(fast(tmp_path, f"model._target_={target}"))
    assert str(err.value).startswith(f"model._target_={target!r} is an alias") and why in str(err.value)
    assert len(str(err.value).splitlines()) == 1
