"""Bad inputs at every entry point (train, evaluate, benchmark, report, sweep CLIs and the Python API),
one or more per config group: each ends non-zero in one ``encons: error: ...; allowed: ...`` line naming
the key or file, with no traceback; the API raises encons' own error types. Run in this process. A value the
checker refuses at build (constructors' bounds, types, ranges) is in tests/config/test_errors.py, not again here."""

from __future__ import annotations

import pytest

from encons.infra.errors import EnconsError
from tests.helpers import in_process

# placeholders: {tmp} this test's folder, {file} a plain file in it, {empty} an empty folder in it,
# {run} a finished tiny training run, {ckpt} its best checkpoint, {bad_ckpt} a truncated checkpoint,
# {rows} a benchmark folder whose one result row is cut short
TRAIN = [  # (overrides, text the error line must hold)
    # system
    (["system=from_file"], "system.path"),
    (["system=from_file", "system.path={empty}"], "system.path="),
    (["system=cartpole", "model=node", "system.u_max=nan"], "system.u_max=nan"),
    (["system=cartpole", "model=node", "system.init_range=[0.5,inf,0.05,3.0]"], "system.init_range"),
    (["system=mass_spring", "system.mass=[-1]"], "system.mass="),
    (["system=pendulum", "system.lengths=0"], "system.lengths=0"),
    (["system=pendulum", "system.g=-9.81"], "system.g=-9.81"),
    (["system=nope"], "system=nope is unknown; allowed:"),
    # data
    (["data.batch_size=0"], "data.batch_size=0"),
    (["data.dt=nan"], "data.dt=nan"),
    (["data.n_steps=0"], "data.n_steps=0"),
    (["data.substeps=0"], "data.substeps=0"),
    # model
    (["model=nope"], "model=nope is unknown; allowed: chnn,"),
    (["model.hidden=0"], "model.hidden=0; allowed: a positive integer"),
    (["model.hidden=abc"], "model.hidden='abc'"),
    (["model=chnn", "system=mass_spring"], "model"),
    # integrator, regulariser, optim, observation
    (["integrator=nope"], "integrator=nope is unknown; allowed: dopri5, euler, midpoint, rk4"),
    (["integrator=dopri5", "integrator.rtol=0"], "integrator.rtol=0"),
    (["optimizer.lr=0"], "optimizer.lr=0"),  # and lr=-1: the same bound
    (["optimizer.lr=inf"], "optimizer.lr=inf"),
    (["optimizer=nope"], "optimizer=nope"),
    (["scheduler=plateau", "scheduler.factor=0"], "scheduler.factor=0"),
    (["system=pixel_pendulum", "observation.latent=1"], "observation.latent=1"),
    # trainer, logger, callbacks, paths, top level
    (["trainer.max_epochs=0"], "trainer.max_epochs=0; allowed: an integer >= 1"),
    (["trainer.max_epochs=-1"], "trainer.max_epochs=-1"),
    (["logger=nope"], "logger=nope"),
    (["logger=csv", "logger.csv.save_dir={file}"], "logger.csv.save_dir="),
    (["paths.cache_dir={file}"], "paths.cache_dir="),
    (["objective=nope"], "objective=nope"),
    (["optimized_metric=val/nope"], "optimized_metric="),
    (["ckpt_path={tmp}/nope.ckpt"], "ckpt_path="),
    (["ckpt_path={empty}"], "ckpt_path="),
    (["ckpt_path={bad_ckpt}"], "ckpt_path="),
    (["ckpt_path=last"], "ckpt_path=last: no earlier run"),
    (["system=from_file", "system.path={file}"], "file.txt"),
    (["observation=nope"], "observation=nope"),
    (["regulariser=hamiltonian", "model=symo"], "regulariser="),
    (["compile=maybe"], "compile="),
    (["trainer.devices=0"], "trainer.devices=0"),
    (["hydra.run.dir={file}/run"], "file.txt"),
    (["debug=nope"], "debug=nope"),
    (["experiment=nope"], "experiment=nope"),
    # sweeps
    (["-m", "sweeps=nope"], "sweeps=nope"),
    (["-m", "sweeps=optuna", "optimizer.lr=tag(log,interval(1e-2,1e-4))"], "optimizer.lr"),
    (
        [
            "-m",
            "sweeps=optuna",
            "sweeps.storage=sqlite:///{tmp}/nope/x.db",
            "optimizer.lr=tag(log,interval(1e-4,1e-2))",
        ],
        "sweeps.storage=",
    ),
    (["-m", "sweeps=optuna", "hydra.sweeper.max_failure_rate=2"], "hydra.sweeper.max_failure_rate=2"),
]

OTHER = [  # (module, argv, text the error line must hold)
    ("encons.evaluate", ["{file}"], "file.txt"),
    ("encons.evaluate", ["{empty}"], "empty"),
    ("encons.evaluate", ["{run}", "model=hnn"], "model=hnn"),
    ("encons.evaluate", ["{run}", "ckpt=nope"], "ckpt='nope'"),
    ("encons.evaluate", ["{run}", "data.test_steps=-1"], "data.test_steps=-1"),
    ("encons.evaluate", ["{run}", "horizon=0"], "horizon=0"),
    ("encons.evaluate", ["{bad_ckpt}"], "bad.ckpt"),
    ("encons.benchmark", ["profile=nope"], "profile=nope"),
    ("encons.benchmark", ["seeds=[]", "out={tmp}/bench"], "seeds=[]"),
    ("encons.benchmark", ["seeds=[-1]", "out={tmp}/bench"], "seeds=[-1]"),
    ("encons.benchmark", ['train=["trainer.max_epochs=-1"]', "out={tmp}/bench"], "trainer.max_epochs=-1"),
    ("encons.benchmark", ["out={file}"], "out="),
    ("encons.benchmark", ["n_train=[0]", "out={tmp}/bench"], "n_train=0"),
    ("encons.benchmark", ["threads=0", "out={tmp}/bench"], "threads=0"),
    ("encons.report", ["{file}"], "file.txt"),
    ("encons.report", ["{empty}"], "empty"),
    ("encons.report", ["{tmp}/nope"], "nope"),
    ("encons.report", ["{rows}"], "result.json"),
    ("encons.benchmark", ["models=[nope]", "out={tmp}/bench"], "model=nope"),
    ("encons.sweep", ["sqlite:///{tmp}/nope/x.db", "study"], "sweeps.storage="),
    ("encons.sweep", ["sqlite:///{tmp}/x.db", "study"], "study='study'"),
]


def _cases(cases, ids):
    return [pytest.param(*case, id=i) for case, i in zip(cases, ids)]


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    """A tiny finished training run (shared by the cases that need one)."""
    from encons.entry import api

    root = tmp_path_factory.mktemp("finished")
    cfg = api.compose("debug=fast", "trainer.max_epochs=1", output_dir=root / "run", cache_dir=root / "cache")
    return api.train(cfg, summary=False)


@pytest.fixture
def places(tmp_path, finished_run):
    (tmp_path / "file.txt").write_text("not what was asked for")
    (tmp_path / "empty").mkdir()
    (tmp_path / "rows" / "runs" / "a").mkdir(parents=True)
    (tmp_path / "rows" / "runs" / "a" / "result.json").write_text('{"system": "pend')
    bad = tmp_path / "bad.ckpt"
    bad.write_bytes(finished_run.checkpoint.read_bytes()[:5000])
    return {
        "tmp": str(tmp_path),
        "file": str(tmp_path / "file.txt"),
        "empty": str(tmp_path / "empty"),
        "run": str(finished_run.run_dir),
        "ckpt": str(finished_run.checkpoint),
        "bad_ckpt": str(bad),
        "rows": str(tmp_path / "rows"),
    }


def _assert_one_line(proc, key: str) -> None:
    assert proc.returncode not in (0, None) and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    last = proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else ""
    assert last.startswith("encons: error: ") and key in last and "; allowed: " in last, proc.stderr[-3000:]


@pytest.mark.parametrize("args, key", _cases(TRAIN, [" ".join(a) for a, _ in TRAIN]))
def test_train_cli(places, tmp_path, monkeypatch, args, key):
    monkeypatch.chdir(tmp_path)
    proc = in_process(
        "encons.train",
        [
            "debug=fast",
            f"hydra.run.dir={tmp_path / 'run'}",
            f"hydra.sweep.dir={tmp_path / 'multi'}",
            *(a.format(**places) for a in args),
        ],
        monkeypatch,
    )
    _assert_one_line(proc, key.format(**places))


@pytest.mark.parametrize("module, argv, key", _cases(OTHER, [f"{m} {' '.join(a)}" for m, a, _ in OTHER]))
def test_other_cli(places, tmp_path, monkeypatch, module, argv, key):
    monkeypatch.chdir(tmp_path)
    _assert_one_line(in_process(module, [a.format(**places) for a in argv], monkeypatch), key.format(**places))


def _api_cases():
    from encons.entry import api

    return {
        "train a list": (lambda p: api.train(["model=nope"]), "model=nope"),
        "train a string": (lambda p: api.train("model=nope"), "model=nope"),
        "compose a list": (lambda p: api.compose(["model=nope"]), "model=nope"),
        "compose unknown": (lambda p: api.compose("model=nope"), "model=nope"),
        "load nothing": (lambda p: api.load(p["tmp"] + "/nope"), "nope"),
        "load a file": (lambda p: api.load(p["file"]), "file.txt"),
        "load a damaged checkpoint": (lambda p: api.load(p["bad_ckpt"]), "bad.ckpt"),
        "evaluate a group change": (lambda p: api.evaluate(p["run"], ["model=hnn"]), "model=hnn"),
        "catalogue unknown": (lambda p: api.catalogue("nope"), "nope"),
    }


API = [
    "train a list",
    "train a string",
    "compose a list",
    "compose unknown",
    "load nothing",
    "load a file",
    "load a damaged checkpoint",
    "evaluate a group change",
    "catalogue unknown",
]


@pytest.mark.parametrize("name", _cases([(n,) for n in API], API))
def test_api_raises_encons_errors(places, tmp_path, monkeypatch, name):
    monkeypatch.chdir(tmp_path)
    call, key = _api_cases()[name]
    with pytest.raises(EnconsError) as caught:
        call(places)
    line = str(caught.value)
    assert "\n" not in line and key in line and "; allowed: " in line, line
