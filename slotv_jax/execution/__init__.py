"""Run a plan on a real Franka arm (to be completed)."""
