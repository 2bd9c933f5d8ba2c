"""atc-nf-env."""
