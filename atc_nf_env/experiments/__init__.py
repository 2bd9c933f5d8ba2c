"""Reproduction experiments of the paper's section IV."""
