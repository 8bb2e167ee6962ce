"""Fixed slot indices shared by the kernel and the term hooks.

Hooks receive small float arrays rather than objects so that numba can compile them;
these constants name the slots. All values SI.
"""

# ctx: what a hook may read about the moment and the robot (read only).
CTX_MODE = 0  # 0 = on the ground, 1 = upside down (wheels in the air)
CTX_T = 1  # time since the start of the simulation, s
CTX_W = 2  # weight carried by the wheels on the ground, (m + payload) g, N
CTX_MASS = 3  # m + payload, kg
CTX_L = 4  # half wheelbase L, m
CTX_LW = 5  # half track l, m
CTX_R = 6  # wheel radius r, m
CTX_G = 7  # gravity, m/s^2
CTX_PSI = 8  # heading psi, rad
CTX_SIGN_PHI = 9  # sign width for wheel speeds, rad/s
CTX_SIGN_SIGMA = 10  # sign width for roller slip speeds, m/s
CTX_V_NOMINAL = 11  # open-circuit battery voltage V_batt, V
CTX_SIZE = 12

MODE_GROUND = 0.0
MODE_UPSIDE_DOWN = 1.0

# elec: electrical slots that terms adjust before the motor currents are solved.
ELEC_R_BATT = 0  # battery internal (series) resistance, ohm (terms add)
ELEC_I_Q = 1  # quiescent electronics current drawn from the battery, A (terms add)
ELEC_RA_SCALE = 2  # 2..5: winding resistance multiplier per motor (terms multiply)
ELEC_SIZE = 6

GRAVITY = 9.80665  # m/s^2
