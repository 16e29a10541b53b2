"""Tilt-method calibration of the Chekan-AM marine/airborne gravimeter.

Data flow::

    emulator ⇄ serial ⇄ hw drivers → acquisition → record (chekan-record/1 CSV)
    record / legacy protocol → model + data → estimator (classical | map | bayes)
      → result (chekan-result/1 JSON + ArviZ NetCDF) → certificate · archive → history

Equation numbers in docstrings refer to Sokolov et al., "Calibration of the
Chekan-AM gravimeter by the tilt method" (the reference paper).
"""

__version__ = "0.3.9"
