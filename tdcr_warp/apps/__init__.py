"""What a user does with solutions: tip control, inverse kinematics, calibration on measured data,
uncertainty, sweeps and the gain search."""
