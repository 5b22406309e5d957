"""The config layer: the one validation pass (``check``: :class:`~encons.config.check.Request`,
:class:`~encons.config.check.Checked`) and target trust (``trust``: what may be instantiated)."""
