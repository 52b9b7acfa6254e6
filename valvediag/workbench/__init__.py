"""Model workbench (provisional init)."""
from .data import LoopData, WorkbenchDataError, prepare_loop
from .diagnosis import Diagnosis, diagnose_fit
from .effects import EFFECTS, EFFECT_NAMES
from .fit import Theta
from .model import LoopModel, ModelFit, fit_model
from .suggest import ErrorLadder, Suggestions, diagnose, forward_select, suggest_effects
from .size import estimate_valve_size
