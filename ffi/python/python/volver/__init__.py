"""volver from Python: volumetric verification of multi-axis machine tools with a laser tracker.

The functions call volver's library (the facade the ``volver`` command-line tool calls) and
return what the CLI's ``--json`` prints, as plain Python objects, with numpy arrays for points
and commands. Units are in the names: ``emm_um`` (µm), ``points_mm`` / ``tool_points_mm``
(N × 3, mm), commands in the machine's file units (mm, degrees), parameters in mm and rad.

Machines are a machine file (TOML) or an embedded machine's name (``presets()``); the XCFZ
grinder of the paper when ``machine`` is None. Errors raise ``VolverError`` subclasses carrying
``file``, ``line`` and ``field`` where volver knows them.

>>> import volver
>>> sorted(volver.presets())
['head-head', 'head-table', 'table-table', 'xcfz']
"""

from ._volver import (
    FileError,
    ImplausibleError,
    InputError,
    MismatchError,
    ModelError,
    NotSolvedError,
    RefusedError,
    RequestError,
    REVERSAL_TOLERANCE_UM,
    SingularError,
    SolverError,
    VolverError,
    __version__,
    compensate_points,
    demo_data,
    describe,
    diagnose,
    identify,
    measurements,
    plan,
    predict,
    presets,
    simulate,
    tables,
    uncertainty,
)

__all__ = [
    "VolverError",
    "InputError",
    "FileError",
    "RequestError",
    "MismatchError",
    "ModelError",
    "SolverError",
    "NotSolvedError",
    "SingularError",
    "ImplausibleError",
    "RefusedError",
    "__version__",
    "REVERSAL_TOLERANCE_UM",
    "presets",
    "describe",
    "measurements",
    "simulate",
    "demo_data",
    "identify",
    "diagnose",
    "uncertainty",
    "predict",
    "compensate_points",
    "tables",
    "plan",
]
