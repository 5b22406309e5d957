"""Lightning's checkpoint writer (its ``CheckpointIO`` plugin seam), made atomic on local disks."""

from __future__ import annotations

from typing import Any

from lightning.fabric.plugins.io.torch_io import TorchCheckpointIO
from lightning.fabric.utilities.types import _PATH

from encons.io import save_checkpoint


class AtomicCheckpointIO(TorchCheckpointIO):
    """Writes each checkpoint through :func:`encons.io.save_checkpoint`: a temporary file in the
    checkpoint's own folder, fsync, rename. Lightning's own writer stages the file in the system's
    temporary folder and moves it (a copy across disks, which a full disk cuts short under the final
    name); here a full or read-only disk is one ``WriteError`` and the earlier checkpoint stays. Reading and
    removing are Lightning's."""

    def save_checkpoint(self, checkpoint: dict[str, Any], path: _PATH, storage_options: Any | None = None) -> None:
        if storage_options is not None:
            raise TypeError(f"{type(self).__name__}.save_checkpoint takes no storage_options")
        save_checkpoint(checkpoint, path)
