"""``bench/experiments/kernel_variant_ab.py``'s variants still apply to the package's sources:
each edit finds its text exactly as often as it expects (the script refuses otherwise, and
a variant that no longer applies would leave a claim in the README without its command)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SPEC = importlib.util.spec_from_file_location("kernel_variant_ab", ROOT / "bench" / "experiments" / "kernel_variant_ab.py")
assert SPEC is not None and SPEC.loader is not None
VARIANT_AB = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(VARIANT_AB)


#: Variants that became the kernel's own form: ``commands-call`` since the kernel dropped
#: numba-level inlining of its scalar path's helpers (it shortened the first compilation,
#: at the same speed), so its edit has nothing left to change.
ADOPTED = {"commands-call"}


@pytest.mark.parametrize("variant", sorted(set(VARIANT_AB.VARIANTS) - ADOPTED))
def test_each_variant_edits_the_source_it_names(variant: str) -> None:
    for file_name, old, new, count in VARIANT_AB.VARIANTS[variant]:
        text = (ROOT / "atc_nf_env" / file_name).read_text()
        assert text.count(old) == count
        assert new not in text  # the variant changes something


@pytest.mark.parametrize("variant", sorted(ADOPTED))
def test_adopted_variant_is_the_source(variant: str) -> None:
    for file_name, old, new, _ in VARIANT_AB.VARIANTS[variant]:
        text = (ROOT / "atc_nf_env" / file_name).read_text()
        assert old not in text and new in text
