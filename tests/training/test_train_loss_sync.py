"""Issue 51: under DDP the logged train/loss was rank 0's alone; it is reduced over the ranks (a no-op on one
device). The two-process check is tests/training/test_ddp.py."""


def test_train_loss_is_logged_with_sync_dist(tmp_path, monkeypatch):
    from encons.entry.api import build
    from encons.training.build import compose

    cfg = compose(
        ["model=node", "system=pendulum1", "debug=fast", "logger=none"],
        output_dir=tmp_path / "run",
        cache_dir=tmp_path / "cache",
    )
    data, module = build(cfg)
    logged = {}
    monkeypatch.setattr(module, "log", lambda name, value, **kw: logged.setdefault(name, kw))
    module.training_step(next(iter(data.train_dataloader())), 0)
    assert logged["train/loss"].get("sync_dist") is True
