"""Fixtures for every test."""

from __future__ import annotations

import pytest

from atc_nf_env import kernel


@pytest.fixture(autouse=True)
def kernel_paths_by_batch_size(monkeypatch: pytest.MonkeyPatch) -> None:
    """Each test starts with the kernel choosing its path by batch size, as a fresh process
    does: a test that reset the MPC (``kernel.load_paths``: the lane path for every size)
    would otherwise leave the later tests' one-world and small-batch flights on the lanes,
    and the tests comparing the paths would compare the lanes with themselves."""
    monkeypatch.setattr(kernel, "_lanes_for_every_size", False)
