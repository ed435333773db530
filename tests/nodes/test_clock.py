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


def test_a_pipelined_world_s_ticks_are_stepped_in_order_each_at_its_own_time_and_a_plain_one_s_from_the_latest():
    """With a lag the world publishes tick k+1 while the node steps tick k: the node steps k+1 next (not a later
    one) and its clock says tick k+1's time meanwhile; without one a node behind goes on from the latest tick."""
    t = LocalTransport()
    ks = KeySpace("clk")
    stop = threading.Event()
    piped, plain = LockstepClock(t, ks, "a"), LockstepClock(t, ks, "b", cell="other")
    pub, other = t.publisher(ks.clock()), t.publisher(ks.clock("other"))
    for tick in (5, 6):
        pub(encode(Clock(t=tick * 0.005, tick=tick, lag=1)))
        other(encode(Clock(t=tick * 0.005, tick=tick)))
    assert piped.wait_tick(stop) == (5, [], 1) and piped.now() == 0.025  # not the latest's 0.03
    assert piped.wait_tick(stop) == (6, [], 1) and piped.now() == 0.03
    assert plain.wait_tick(stop) == (6, [], 0)
    for tick in range(7, 12):  # a pipelined node far behind goes on from the tick before the latest
        pub(encode(Clock(t=tick * 0.005, tick=tick, lag=1)))
    assert piped.wait_tick(stop)[0] == 10
