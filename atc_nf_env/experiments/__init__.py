"""Reproduction experiments of the paper's section IV.

They live in the core package, beside the simulator they study, and reach the policies
they fly (the NF alone, the MCMC-MPC) through the policy registry
(``atc_nf_env.policy.make_policy("nf" | "mpc", ...)``), never by importing the packages
built on the core.
"""
