"""
Model workbench: compare a physical loop model with the measurements, see
where it fails, learn which physical effect is missing, add it and watch the
error fall.

The loop model is a chain of named, swappable effects (as pvlib's
``ModelChain``), driven by the measured OP and predicting the PV::

    OP -> valve (deadband | stiction, saturation, characteristic) -> dead_time -> lag
       -> plant input minus load (operating point, drift, oscillating load)
       -> plant (integrating or self-regulating) -> PV -> reading (quantisation)

Typical use, here on a simulated loop with a loose valve (dead band 3) and a
dead time of 10 s that the first model lacks::

    >>> from valvediag import simulate_loop
    >>> sim = simulate_loop(kc=2.0, ti=60.0, tau=60.0, sample_time=1.0, duration=3600,
    ...                     sp_step=1.0, valve="backlash", valve_params={"DB": 3.0},
    ...                     dead_time=10.0, noise_std=0.005, seed=1)
    >>> pv, op = sim.pv, sim.op                         # or a measured record
    >>> from valvediag.workbench import prepare_loop, LoopModel, suggest_effects, forward_select
    >>> data = prepare_loop(pv, op, sample_time=1.0)
    >>> fit = LoopModel(("deadband",)).fit(data)       # ModelFit, .plot(), .plot_chain()
    >>> fit.diagnose().plot("ccf")                      # where it fails (Diagnosis)
    <Axes: title={'center': 'residual-OP cross-correlation (99 % band)'}, ...>
    >>> sug = suggest_effects(fit)                      # which effect is missing
    >>> print(sug.table()); sug.best.effect
    model         fit %  held-out RMSE       BIC  evidence
    deadband       97.0       0.008926  -17013.3  (base)
    + dead_time    98.3       0.005055  -19385.7  accepted; residual-OP cross-correlation ...
    + lag          98.3       0.005097  -19328.1  accepted; residual vs OP rate ...
    ...
    'dead_time'
    >>> ladder = forward_select(data, ("deadband",))    # add, refit, repeat
    >>> ladder.plot(); print(ladder.table())
    <Axes: title={'center': 'error ladder'}, ylabel='held-out RMSE [PV]'>
    step model               k  fit %  held-out RMSE       BIC  parameters
    0    deadband            3   97.0       0.008926  -17013.3  gain=0.03189, DB=3.814, bias=-3.91e-05
    1    deadband+dead_time  4   98.3       0.005055  -19385.7  gain=0.01667, DB=2.999, dead_time=10, bias=4.608e-06
         (dead_time or lag: this record cannot tell them apart)

The PV prediction is a free simulation re-initialised every ``horizon``
samples (to the best initial state of each segment), fitted on alternating
training blocks and scored on held-out blocks. For the nightly scan,
:func:`estimate_valve_size` sizes a valve fault (dead band, or S and J), and
:func:`valve_kind` tells a sticky from a loose valve behind a lag.

References
----------
.. [1] Kano, M., Maruta, H., Kugemoto, H., Shimizu, K. (2004). Practical model
   and detection algorithm for valve stiction. IFAC DYCOPS 7, Boston.
.. [2] Choudhury, M. A. A. S., Thornhill, N. F., Shah, S. L. (2005).
   Modelling valve stiction. Control Engineering Practice 13, 641-658.
.. [3] He, Q. P., Wang, J., Pottmann, M., Qin, S. J. (2007). A curve fitting
   method for detecting valve stiction in oscillating control loops.
   Ind. Eng. Chem. Res. 46, 4549-4560.
.. [4] Hägglund, T. (2007). Automatic on-line estimation of backlash in
   control loops. Journal of Process Control 17, 489-499.
.. [5] Ljung, L. (1999). System Identification: Theory for the User, 2nd ed.
   Prentice Hall (residual analysis, sec. 16.6).
"""
from .data import LoopData, WorkbenchDataError, prepare_loop
from .diagnosis import Diagnosis, WorstSegment, diagnose_fit
from .effects import EFFECT_NAMES, EFFECTS, PLANT_PARAMS, Effect, Param, check_effects
from .fit import Theta
from .kind import ValveKind, valve_kind
from .model import LoopModel, ModelFit, fit_model
from .sensor import PVGrid, pv_grid, quantised_mean
from .size import estimate_valve_size, size_window
from .suggest import (
                      ErrorLadder,
                      Evidence,
                      LadderStep,
                      Suggestion,
                      Suggestions,
                      diagnose,
                      effect_evidence,
                      forward_select,
                      suggest_effects,
)

__all__ = ["LoopData", "WorkbenchDataError", "prepare_loop", "Diagnosis", "WorstSegment",
           "diagnose_fit", "EFFECTS", "EFFECT_NAMES", "PLANT_PARAMS", "Effect", "Param",
           "check_effects", "Theta", "LoopModel", "ModelFit", "fit_model",
           "PVGrid", "pv_grid", "quantised_mean", "estimate_valve_size", "size_window",
           "ErrorLadder", "Evidence", "LadderStep", "Suggestion",
           "Suggestions", "diagnose", "effect_evidence", "forward_select", "suggest_effects",
           "ValveKind", "valve_kind"]
