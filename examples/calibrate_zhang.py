"""Zhang et al. 2010 on a simulated navigation-grade triad (their Table 3 settings): calibration without attitude
knowledge, Zhang's parameters and their errors, and the inter-triad misalignment.

    python examples/calibrate_zhang.py
"""

from __future__ import annotations

from rimu.calibration import Zhang
from rimu.calibration.zhang import zhang_parameters
from rimu.geometry import triad3
from rimu.sim import Simulator, zhang_scheme
from rimu.units import MS2_TO_UG, RAD_TO_ARCSEC, RS_TO_DH

g = triad3()
sim = Simulator({"gyro": g, "accel": g}, arw_deg_sqrt_h=0.1 / 60, vrw_ug_sqrt_hz=500, table_angle_error_arcsec=2,
                lever_arm_m=[0.05, 0, 0], perturbation_ug=50, seed=3)
run = sim.run(zhang_scheme())
result = Zhang().fit(run.session)
print(result.table())
zt, ze = zhang_parameters(run.truth), zhang_parameters(result.to_calibration())
print("errors: accel scale ppm", ((ze["k_a"] / zt["k_a"] - 1) * 1e6).round(1),
      "| accel misalignment arcsec", ((ze["alpha"] - zt["alpha"]) * RAD_TO_ARCSEC).round(1),
      "| accel bias ug", ((ze["b_a"] - zt["b_a"]) * MS2_TO_UG).round(1))
print("errors: gyro scale ppm", ((ze["k_g"] / zt["k_g"] - 1) * 1e6).round(2),
      "| gyro misalignment arcsec", ((ze["gamma"] - zt["gamma"]) * RAD_TO_ARCSEC).round(2),
      "| gyro bias deg/h", ((ze["b_g"] - zt["b_g"]) * RS_TO_DH).round(4))
print("inter-triad misalignment error arcsec", ((ze["theta"] - zt["theta"]) * RAD_TO_ARCSEC).round(1),
      "reported std", (result.extra["inter_triad_std_rad"] * RAD_TO_ARCSEC).round(1))
