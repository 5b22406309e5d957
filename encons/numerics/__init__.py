"""Numerics on top of the models: rollouts (``integrators``), the evaluation pipeline and its metrics, the soft
constraints (``regularisers``) and the :class:`~encons.numerics.learner.Learner` protocol that evaluators and
objectives read."""
