"""Simulation clocks: a forged clock message far ahead is refused, the world's real clock goes on."""

import threading

from contactflow.nodes.clock import MAX_TICK_JUMP, MAX_TIME_JUMP, LockstepClock, SimClock
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.messages import Clock
from contactflow.nodes.transport import LocalTransport
from contactflow.nodes.wire import encode


def test_a_forged_clock_far_ahead_is_refused_and_the_real_clock_goes_on():
    t = LocalTransport()
    ks = KeySpace("clk")
    sim, lock = SimClock(t, ks), LockstepClock(t, ks, "n")
    pub = t.publisher(ks.clock())
    pub(encode(Clock(t=10.0, tick=2000)))  # a node may join a world that ran a while: the first is taken
    assert sim.now() == 10.0 and lock.now() == 10.0
    pub(encode(Clock(t=10.0 + MAX_TIME_JUMP + 1.0, tick=2001)))  # forged: an hour ahead
    pub(encode(Clock(t=10.0, tick=2000 + MAX_TICK_JUMP + 1)))  # forged: a tick far ahead
    assert sim.rejected == 1 and lock.rejected == 2
    pub(encode(Clock(t=10.005, tick=2001)))  # the world's next tick is taken as before
    assert sim.now() == 10.005 and lock.now() == 10.005
    assert lock.wait_tick(threading.Event())[0] == 2001
