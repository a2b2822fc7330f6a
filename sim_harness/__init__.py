"""quadnav's simulation harness: worlds, synthetic D435 depth, a kinematic quad, an RL
environment and an emulated PX4 on real MAVLink. Stands in for hardware in CI and dry runs."""
