"""Infrastructure, the lowest layer: errors, declared bounds, paths, files written atomically, checkpoints read
safely, threads, progress, and the one place upstream private internals are touched (``compat``). No physics,
no training."""
