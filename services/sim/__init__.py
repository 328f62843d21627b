"""Simulation service: MuJoCo robot following one solver's JointCommands."""
