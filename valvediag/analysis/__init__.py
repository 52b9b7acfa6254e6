"""
One loop, pure numerics: arrays in, frozen results out.

* :mod:`~valvediag.analysis.align`: a loop's tags on one uniform grid, never
  bridging bad states or long gaps (:func:`align_loop`).
* :mod:`~valvediag.analysis.quality`: the data-quality screen (gaps, bad
  states, frozen sensor, compression, manual mode, saturation).
* :mod:`~valvediag.analysis.oscillation`: oscillation detection, period,
  amplitude and Thornhill's regularity.
* :mod:`~valvediag.analysis.linearity`: the shape of the mean cycle
  (harmonic distortion, ramps), which tells a valve from a sinusoid.
* :mod:`~valvediag.analysis.bi`: the Backlash Index of Farenzena &
  Trierweiler (2012), literal and robust.
* :mod:`~valvediag.analysis.signature`: the valve's behaviour read back from
  the PV (a Hammerstein fit of linear, sticky and loose valves), stick-slip
  events without a limit cycle, Horch's cross-correlation test.
* :mod:`~valvediag.analysis.bumps`: a level's set-point steps read as bump
  tests of its valve.
* :mod:`~valvediag.analysis.setpoint`: a set point the export did not hold,
  read back from the controller's kicks.
* :mod:`~valvediag.analysis.travel`: a recorded valve position read against
  the OP (follows, lags and jumps, lags without a jump).
* :mod:`~valvediag.analysis.classify`: one verdict for one record.
* :mod:`~valvediag.analysis.trend`: the PV-and-OP trend the results' plots draw on.
"""
from .align import AlignedLoop, align_loop
from .bi import BacklashIndex, backlash_index
from .bumps import SetPointBumps, setpoint_bumps
from .classify import LoopDiagnosis, classify_loop
from .oscillation import Oscillation, detect_oscillation
from .quality import DataQuality, quality_metrics
from .signature import StickSlipEvents, ValveSignature, stick_slip_events, valve_signature
from .travel import ValveTravel, valve_travel

__all__ = ["AlignedLoop", "align_loop", "BacklashIndex", "backlash_index", "SetPointBumps",
           "setpoint_bumps", "LoopDiagnosis",
           "classify_loop", "Oscillation", "detect_oscillation", "DataQuality", "quality_metrics",
           "ValveSignature", "valve_signature", "StickSlipEvents", "stick_slip_events",
           "ValveTravel", "valve_travel"]
