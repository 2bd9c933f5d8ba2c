"""Fixtures for every test."""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest

from atc_nf_env import kernel


@pytest.fixture(autouse=True, scope="session")
def sb3_logs_in_pytests_temp_folder(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """SB3's ``learn`` without a tensorboard folder logs to ``$SB3_LOGDIR``, else to a new
    ``SB3-<date>`` folder in the system temp directory that nothing removes: point it into
    pytest's temp folder (rotated by pytest), for this process and the commands it starts."""
    saved = os.environ.get("SB3_LOGDIR")
    os.environ["SB3_LOGDIR"] = str(tmp_path_factory.mktemp("sb3-logs"))
    yield
    if saved is None:
        os.environ.pop("SB3_LOGDIR", None)
    else:
        os.environ["SB3_LOGDIR"] = saved


@pytest.fixture(autouse=True)
def kernel_paths_by_batch_size(monkeypatch: pytest.MonkeyPatch) -> None:
    """Each test starts with the kernel choosing its path by batch size, as a fresh process
    does: a test that reset the MPC (``kernel.load_paths``: the lane path for every size)
    would otherwise leave the later tests' one-world and small-batch flights on the lanes,
    and the tests comparing the paths would compare the lanes with themselves."""
    monkeypatch.setattr(kernel, "_lanes_for_every_size", False)
