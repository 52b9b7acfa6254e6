"""
Synthetic plants with a known answer: historian exports, a loop registry and
the truth of every loop (:func:`synth_plant`), with digital states, gaps and
historian compression (:func:`exception_deadband`, :func:`swinging_door`).
"""
from .plant import SynthPlant, exception_deadband, swinging_door, synth_plant

__all__ = ["synth_plant", "SynthPlant", "exception_deadband", "swinging_door"]
