"""The synthetic campus scene simulator (`tracklabel simulate`): an HDL-32E on a vehicle
driving a campus loop among buildings, trees, bushes, parked and moving cars, cyclists and
pedestrians, written as a SemanticKITTI sequence with ground-truth labels."""

from __future__ import annotations

from research.simulation.simulate import SimulationSummary, simulate_frame, simulate_sequence

__all__ = ["SimulationSummary", "simulate_frame", "simulate_sequence"]
