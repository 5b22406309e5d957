"""What a test run scores: one :class:`Evaluator` per way of scoring, chosen in ``conf/evaluators``
(``evaluators=[states]`` by default; ``[pixels]`` on pixel systems; ``[states,santos]`` on Santos et
al.'s controlled systems). Interface and data flow: ``encons.evaluators.base``."""

from encons.evaluators.base import Evaluator, Result, TestBatch
from encons.evaluators.pixels import Pixels
from encons.evaluators.santos import SantosMetrics
from encons.evaluators.states import States

__all__ = ["Evaluator", "Pixels", "Result", "SantosMetrics", "States", "TestBatch"]
