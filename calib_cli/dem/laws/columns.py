"""The columns of an interaction's parameter row (``prm[row, column]``): what the laws read.

Rows: 0 particle-particle, 1 floor, 2 cylinder. A column is a value of the interaction or a constant
derived from it once per run (:func:`calib_cli.dem.materials.param_row`), never a switch: which law a
run uses is its :class:`~calib_cli.dem.laws.ContactModel`.
"""

PP, FLOOR, CYL = 0, 1, 2
#: E*, G*, static and rolling friction, damping ratio, surface energy g, the JKR constants k^(1/3) and
#: 4 sqrt(pi g E* k^(1/3)), sqrt(4 G*/E*), the rolling spring's stiffness and damping, the liquid
#: bridge's strength 2 pi gamma cos(theta), rupture and gap-scale coefficients
(E_S, G_S, MU_S, MU_R, BETA, GAMMA, K13, ATT, T_RATIO, K_ROLL, G_ROLL,
 BRIDGE_F, BRIDGE_RUPTURE, BRIDGE_GAP) = range(14)
NCOL = 14

#: columns of a contact's history row: tangential spring (3), contact radius a of the last step,
#: cached R*^(1/3), rolling spring (3), liquid bridge formed (1/0)
SPRING, A_OLD, R13, ROLL_SPRING, BRIDGE = 0, 3, 4, 5, 8
HIST = 9
