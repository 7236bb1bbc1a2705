"""Execution Pack: the Physics Pack with an ABB IRB 6700 placing every box (OMPL-planned transfers)."""

from robobpp.sim.execution.layout import Layout
from robobpp.sim.execution.pack import ExecutionConfig, ExecutionPack, Operation

__all__ = ["ExecutionConfig", "ExecutionPack", "Layout", "Operation"]
