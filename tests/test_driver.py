"""clients/lockstep/driver.py: what the loop does around its exchanges (its physics is tested through
the runs of test_exudyn_client, test_coupling_schemes and the examples)."""

from __future__ import annotations

import os
import signal
import time

import pytest

from conftest import needs_python_sigint

from hydrolink.clients.lockstep.driver import SigintLatch


class _InterruptedWhileFinalized:
    """An object whose finalizer is where the Ctrl-C lands: Python prints the KeyboardInterrupt
    raised there as "Exception ignored" and goes on."""

    def __del__(self) -> None:
        os.kill(os.getpid(), signal.SIGINT)
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:   # the handler runs at the next bytecode boundary, here
            time.sleep(0.001)


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_a_ctrl_c_swallowed_by_a_finalizer_is_lost_without_the_latch_and_raised_by_its_check():
    needs_python_sigint()
    obj = _InterruptedWhileFinalized()
    del obj                                       # the KeyboardInterrupt is lost: nothing raised here
    with SigintLatch() as latch:
        assert signal.getsignal(signal.SIGINT) == latch._handle
        obj = _InterruptedWhileFinalized()
        del obj                                   # lost again, but latched
        assert latch.pending
        with pytest.raises(KeyboardInterrupt):
            latch.check()
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
