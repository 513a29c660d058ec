"""The columns of an interaction's parameter row (``prm[row, column]``) and of a contact's history
row (``ht[k, column]``): what the laws read and keep.

Rows: 0 particle-particle, 1 floor, 2 cylinder. A column is a value of the interaction or a constant
derived from it once per run (:func:`calib_cli.dem.materials.param_row`), never a switch: which law a
run uses is its :class:`~calib_cli.dem.laws.ContactModel`.

The columns below are the built-in laws'. A law with parameters of its own takes its columns with
:func:`allocate` when its module is imported (:mod:`calib_cli.dem.laws` imports every law module
before the kernel reads :data:`NCOL` and :data:`HIST`), so adding a law touches no list here.
"""

PP, FLOOR, CYL = 0, 1, 2
#: E*, G*, static and rolling friction, damping ratio, surface energy g, the JKR constants k^(1/3) and
#: 4 sqrt(pi g E* k^(1/3)), sqrt(4 G*/E*), the rolling spring's stiffness and damping
E_S, G_S, MU_S, MU_R, BETA, GAMMA, K13, ATT, T_RATIO, K_ROLL, G_ROLL = range(11)
#: the built-in laws' columns come first; the laws' own follow (allocate)
BUILT_IN = NCOL = 11

#: columns of a contact's history row: tangential spring (3), contact radius a of the last step,
#: cached R*^(1/3), rolling spring (3)
SPRING, A_OLD, R13, ROLL_SPRING = 0, 3, 4, 5
HIST = 8


def allocate(parameters: int = 0, history: int = 0) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """Take ``parameters`` new columns of the parameter row and ``history`` of the history row for a
    law; returns their indices. Called at a law module's import, before anything compiles."""
    global NCOL, HIST
    prm = tuple(range(NCOL, NCOL + parameters))
    hist = tuple(range(HIST, HIST + history))
    NCOL += parameters
    HIST += history
    return prm, hist
