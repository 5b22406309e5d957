"""Three sweep workers share one Optuna study on a real local PostgreSQL server: every trial is
stored once, none lost, none duplicated (docs/sweeps.md "Beyond one machine")."""

from __future__ import annotations

import glob
import os
import pwd
import shutil
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

import optuna
import pytest
import yaml
from optuna.trial import TrialState

pytestmark = pytest.mark.slow  # starts a PostgreSQL server and three sweep workers

WORKERS, TRIALS_PER_WORKER = 3, 2


def _postgres_bin() -> Path | None:
    """The folder of ``initdb``/``pg_ctl``: on PATH, else Debian's /usr/lib/postgresql/<v>/bin."""
    on_path = shutil.which("pg_ctl")
    if on_path and shutil.which("initdb"):
        return Path(on_path).resolve().parent
    found = sorted(glob.glob("/usr/lib/postgresql/*/bin/pg_ctl"), key=lambda p: int(p.split("/")[4]))
    return Path(found[-1]).parent if found else None


@pytest.fixture
def postgres_url():
    """A throw-away PostgreSQL cluster on a free local port; yields its SQLAlchemy URL."""
    import psycopg  # noqa: F401  (psycopg 3, the driver the project installs: a missing one is an error, not a skip)

    bindir = _postgres_bin()
    if bindir is None:
        pytest.skip("no PostgreSQL server binaries (initdb, pg_ctl): apt-get install -y postgresql")
    user = None
    if os.geteuid() == 0:  # initdb refuses to run as root: use Debian's postgres account
        try:
            user = pwd.getpwnam("postgres")
        except KeyError:
            pytest.skip("running as root without a 'postgres' user for initdb")
    data = Path(tempfile.mkdtemp(prefix="encons-pg-"))
    if user:
        os.chown(data, user.pw_uid, user.pw_gid)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]

    def pg(*args: str) -> None:
        subprocess.run(
            [str(bindir / args[0]), *args[1:]],
            check=True,
            capture_output=True,
            timeout=120,
            user=user.pw_uid if user else None,
            group=user.pw_gid if user else None,
        )

    try:
        pg("initdb", "-D", str(data / "db"), "-U", "postgres", "--auth=trust", "--no-sync")
        pg(
            "pg_ctl",
            "-D",
            str(data / "db"),
            "-l",
            str(data / "log"),
            "-w",
            "start",
            "-o",
            f"-p {port} -k {data} -c listen_addresses=127.0.0.1 -c fsync=off",
        )
        yield f"postgresql://postgres@127.0.0.1:{port}/postgres"
    finally:
        if (data / "db" / "postmaster.pid").exists():
            pg("pg_ctl", "-D", str(data / "db"), "-m", "immediate", "-w", "stop")
        shutil.rmtree(data, ignore_errors=True)


def test_three_workers_share_one_study(postgres_url, tmp_path):
    study = "shared"
    create = [
        str(Path(sys.executable).with_name("optuna")),
        "create-study",
        "--storage",
        postgres_url,
        "--study-name",
        study,
        "--direction",
        "minimize",
        "--skip-if-exists",
    ]
    subprocess.run(create, check=True, capture_output=True, timeout=120)
    env = {**os.environ, "ENCONS_ROOT": str(tmp_path)}
    workers = [
        subprocess.Popen(
            [
                sys.executable,
                "-m",
                "encons.train",
                "-m",
                "sweeps=optuna",
                "model=node",
                "system=pendulum1",
                "debug=fast",
                "test=false",
                "trainer.max_epochs=1",
                "optimizer.lr=tag(log,interval(1e-4,1e-2))",
                f"hydra.sweeper.n_trials={TRIALS_PER_WORKER}",
                f"hydra.sweeper.sampler.seed={k}",
                f"sweeps.storage={postgres_url}",
                f"sweeps.study_name={study}",
            ],
            cwd=tmp_path,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        for k in range(WORKERS)
    ]
    for w in workers:
        out, _ = w.communicate(timeout=600)
        assert w.returncode == 0, out[-3000:]

    trials = optuna.load_study(study_name=study, storage=postgres_url).trials
    assert sorted(t.number for t in trials) == list(range(WORKERS * TRIALS_PER_WORKER))
    assert all(t.state == TrialState.COMPLETE for t in trials), [t.state for t in trials]
    assert len({t.params["optimizer.lr"] for t in trials}) == len(trials), "workers sampled the same point"
    runs = sorted((tmp_path / "multirun" / study).glob("trial_*/.hydra/overrides.yaml"))
    assert len(runs) == len(trials)  # each trial ran exactly once, in its own folder
    for t in trials:
        overrides = yaml.safe_load(
            (tmp_path / "multirun" / study / f"trial_{t.number}/.hydra/overrides.yaml").read_text()
        )
        assert f"++sweeps.trial={t.number}" in overrides
        assert f"optimizer.lr={t.params['optimizer.lr']}" in overrides
