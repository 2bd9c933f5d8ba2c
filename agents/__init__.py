"""Stable-Baselines3 agents trained on the atc-nf-env environments."""
