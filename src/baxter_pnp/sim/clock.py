"""Simulated-time bookkeeping for the fake Baxter: wall-clock pacing, periodic schedules and the time its
messages carry (no ROS).

The fake Baxter advances the physics by fixed steps. Everything periodic (publications, rendering) is scheduled
in simulated seconds with ``RateSchedule``, so rates stay right in simulated time however fast the CPU is;
``RealTimePacer`` only decides how long to sleep in wall time so that simulated time runs at
``real_time_factor`` times wall time (or as fast as possible with a factor of 0, or as fast as the CPU allows
when it cannot keep up). ``MessageClock`` says what the stamps hold: simulated seconds (``sim``, the fake
publishes ``/clock``) or, as a real robot, the wall clock (``wall``).
"""
import time

CLOCKS = ('sim', 'wall')          # --clock: simulated time on /clock, or the wall clock as the real robot
HARNESS_CLOCK = 'sim'             # tests and trial batches: unpaced on /clock, clients started after the first


def default_clock(real_time_factor):
    """The fake's clock when none is given: the wall clock, as a real robot, when paced at 1.0; simulated time
    (``/clock``) at any other ``real_time_factor``: only simulated time runs slower or faster than the wall."""
    return 'wall' if float(real_time_factor) == 1.0 else 'sim'


class RateSchedule:
    """A task due every ``1 / rate_hz`` simulated seconds, first at ``start`` (s)."""

    def __init__(self, rate_hz, start=0.0):
        if not rate_hz > 0:
            raise ValueError(f'rate must be positive, got {rate_hz!r} Hz')
        self.period = 1.0 / float(rate_hz)
        self._next = float(start)

    def due(self, now):
        """True (once) when the task is due at simulated time ``now`` (s); then the next due time is set.

        Due times stay on the grid ``start + k * period`` so the average rate is exact; after a pause
        longer than a period (e.g. a camera closed, then opened) the grid restarts at ``now``.
        """
        if now + 1e-9 < self._next:
            return False
        self._next += self.period
        if self._next <= now:
            self._next = now + self.period
        return True


class RealTimePacer:
    """Sleeps so that simulated time advances ``real_time_factor`` times as fast as wall time.

    ``real_time_factor`` 0 means no sleeping at all. A simulation behind by up to ``max_lag`` wall seconds (a
    busy moment: a burst of frames, the client's computation on the shared cores) catches up at full speed; one
    behind by more (a CPU too slow) moves the reference instead, and the time is lost (``resets``, ``lost``).
    ``wall_clock`` and ``sleep`` are injectable for tests.
    """

    def __init__(self, real_time_factor=1.0, max_lag=0.3, wall_clock=time.monotonic, sleep=time.sleep):
        if real_time_factor < 0:
            raise ValueError(f'real-time factor must be >= 0, got {real_time_factor!r}')
        self.real_time_factor = float(real_time_factor)
        self.max_lag = float(max_lag)
        self._wall_clock, self._sleep = wall_clock, sleep
        self._reference = None          # (wall time, sim time) that pacing is measured from
        self._start = None              # (wall time, sim time) of the first call, for measured_factor()
        self._last = None
        self.resets, self.lost = 0, 0.0    # times the reference was moved, simulated s given up doing so

    def pace(self, sim_time):
        """Sleep until wall time catches up with ``sim_time`` (simulated seconds)."""
        wall = self._wall_clock()
        if self._reference is None:
            self._reference = self._start = (wall, sim_time)
        self._last = (wall, sim_time)
        if self.real_time_factor == 0:
            return
        wall_ref, sim_ref = self._reference
        target = wall_ref + (sim_time - sim_ref) / self.real_time_factor
        if target > wall:
            self._sleep(target - wall)
        elif wall - target > self.max_lag:
            self.resets += 1
            self.lost += (wall - target) * self.real_time_factor
            self._reference = (wall, sim_time)

    def wall_time_of(self, sim_time):
        """The wall instant (s of ``wall_clock``) this pacer holds simulated instant ``sim_time`` (s) to: now
        before the first ``pace`` call; at most ``max_lag`` before the wall clock once pacing (factor > 0)."""
        if self._reference is None or self.real_time_factor == 0:
            return self._wall_clock()
        wall_ref, sim_ref = self._reference
        return wall_ref + (sim_time - sim_ref) / self.real_time_factor

    def measured_factor(self, since=None):
        """Simulated seconds per wall second from ``since`` ((wall s, simulated s); default: the first ``pace``
        call) to the last ``pace`` call (0 before two calls). Ends at the last step paced, so the time a shutdown
        takes does not count."""
        start = since or self._start
        if start is None or self._last is None or self._last[0] <= start[0]:
            return 0.0
        return (self._last[1] - start[1]) / (self._last[0] - start[0])


class MessageClock:
    """The time the fake's messages carry. ``sim``: simulated seconds (``/clock`` published, ``/use_sim_time``
    set). ``wall``: as a real robot, Unix seconds of the wall clock -- the instant ``pacer`` (which must run at
    a real-time factor of 1) holds each simulated instant to, so a message's stamp is within a physics step
    of when it is sent while the fake keeps pace, and stamps stay as evenly spaced as the simulation's.
    ``unix_minus_wall``: Unix time minus the pacer's wall clock (default: measured now for ``time.monotonic``).
    """

    def __init__(self, kind, pacer, unix_minus_wall=None):
        if kind not in CLOCKS:
            raise ValueError(f'clock must be one of {", ".join(CLOCKS)}, got {kind!r}')
        if kind == 'wall' and pacer.real_time_factor != 1.0:
            raise ValueError(f'the wall clock needs a real-time factor of 1 (got {pacer.real_time_factor:g}); '
                             f'use the sim clock to run slower or faster than real time')
        self.kind, self._pacer = kind, pacer
        self._unix_minus_wall = time.time() - time.monotonic() if unix_minus_wall is None else unix_minus_wall

    @property
    def publishes_clock(self):
        """True when the fake publishes ``/clock`` (simulated time)."""
        return self.kind == 'sim'

    def seconds(self, sim_time):
        """The stamp (s) of what happens at simulated time ``sim_time`` (s)."""
        if self.kind == 'sim':
            return sim_time
        return self._unix_minus_wall + self._pacer.wall_time_of(sim_time)
