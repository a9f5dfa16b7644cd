"""MuJoCo Franka stand-in for fiper-ros."""
