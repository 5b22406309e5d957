"""What a test run scores: one :class:`Evaluator` per way of scoring, chosen in ``conf/evaluators``
(``evaluators=[states]`` by default; ``[pixels]`` on pixel systems; ``[states,santos]`` on Santos et
al.'s controlled systems; ``[states,acceleration]`` on Xiao et al.'s). Interface and data flow:
``encons.evaluators.base``."""

from encons.evaluators.acceleration import Acceleration
from encons.evaluators.base import Evaluator, Result, TestBatch
from encons.evaluators.pixels import Pixels
from encons.evaluators.santos import SantosMetrics
from encons.evaluators.states import States

__all__ = ["Acceleration", "Evaluator", "Pixels", "Result", "SantosMetrics", "States", "TestBatch"]
