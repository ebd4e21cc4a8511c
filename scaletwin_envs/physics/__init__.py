"""Simulator-independent physics of the loader: planar kinematics, statics and the soil model."""
