"""Baxter's digital and analog I/O and its navigators, pure (no ROS): the components a real Baxter (SDK 1.2.0)
publishes under ``/robot/digital_io/<name>/state`` and ``/robot/analog_io/<name>/state``, which of them accept
commands, and the ``NavigatorState`` each navigator's buttons, wheel and lights make.

Digital values are booleans (DigitalIOState ON/PRESSED = 1); analog values are the component's raw numbers (the
wheels 0-255, the hand range sensors in mm with 65535 out of range, the torso fan 0-100). Inputs
change only through ``set_input`` (a person pressing a button: in the fake, a test's ``/fake_baxter/`` topic);
outputs through ``command`` (``/robot/digital_io/command``, ``/robot/analog_io/command``), as on the robot.
"""
NAVIGATORS = ('left', 'right', 'torso_left', 'torso_right')
NAVIGATOR_BUTTONS = ('ok', 'back', 'show')       # NavigatorState.buttons[0..2]: the wheel, above it, below it
NAVIGATOR_LIGHTS = ('inner', 'outer')            # NavigatorState.lights[0..1]
ARMS = ('left', 'right')


def _navigator_io(navigator):
    """(button digital inputs, light digital outputs, wheel analog input) names of a navigator."""
    return ([f'{navigator}_button_{b}' for b in NAVIGATOR_BUTTONS], [f'{navigator}_{light}_light'
                                                                     for light in NAVIGATOR_LIGHTS],
            f'{navigator}_wheel')


# The components emulated, of those a real Baxter lists (rostopic list): the cuffs and their buttons, the
# navigators' buttons, wheels and lights, the hand range sensors and the torso fan; {name: initial value}.
DIGITAL_INPUTS = dict.fromkeys(
    [f'{arm}_{part}' for arm in ARMS for part in ('lower_cuff', 'lower_button', 'upper_button')]
    + [name for navigator in NAVIGATORS for name in _navigator_io(navigator)[0]], False)
DIGITAL_OUTPUTS = dict.fromkeys([name for navigator in NAVIGATORS for name in _navigator_io(navigator)[1]], False)
RANGE_OUT_OF_RANGE_MM = 65535.0
ANALOG_INPUTS = dict(dict.fromkeys([_navigator_io(navigator)[2] for navigator in NAVIGATORS], 0.0),
                     **dict.fromkeys([f'{arm}_hand_range' for arm in ARMS], RANGE_OUT_OF_RANGE_MM))
ANALOG_OUTPUTS = {'torso_fan': 0.0}
WHEEL_RANGE = (0, 255)


class IOCommandError(ValueError):
    """A command or input naming an unknown component, an input commanded as an output, or a bad value."""


class IOBoard:
    """The I/O components' values; ``take_changed()`` says which changed since it was last called."""

    def __init__(self):
        self.digital = dict(DIGITAL_INPUTS, **DIGITAL_OUTPUTS)
        self.analog = dict(ANALOG_INPUTS, **ANALOG_OUTPUTS)
        self._changed = set()

    @staticmethod
    def is_input_only(name):
        return name in DIGITAL_INPUTS or name in ANALOG_INPUTS

    def command(self, name, value):
        """Set output ``name`` (a DigitalOutputCommand's bool or an AnalogOutputCommand's number)."""
        if name in DIGITAL_OUTPUTS:
            self._set(self.digital, name, bool(value))
        elif name in ANALOG_OUTPUTS:
            self._set(self.analog, name, float(value))
        elif self.is_input_only(name):
            raise IOCommandError(f'{name!r} is an input: it cannot be commanded')
        else:
            raise IOCommandError(f'unknown I/O component {name!r}')

    def set_input(self, name, value):
        """Set input ``name`` as the world would (a button pressed or released, the wheel turned, a sensor)."""
        if name in DIGITAL_INPUTS:
            self._set(self.digital, name, bool(value))
        elif name in ANALOG_INPUTS:
            if name.endswith('_wheel') and not WHEEL_RANGE[0] <= value <= WHEEL_RANGE[1]:
                raise IOCommandError(f'{name}: a wheel reads {WHEEL_RANGE[0]}..{WHEEL_RANGE[1]}, got {value}')
            self._set(self.analog, name, float(value))
        elif name in DIGITAL_OUTPUTS or name in ANALOG_OUTPUTS:
            raise IOCommandError(f'{name!r} is an output: command it on the robot\'s command topic')
        else:
            raise IOCommandError(f'unknown I/O component {name!r}')

    def _set(self, values, name, value):
        if values[name] != value:
            values[name] = value
            self._changed.add(name)

    def take_changed(self):
        """The names whose value changed since the last call (and, through them, the navigators)."""
        changed, self._changed = self._changed, set()
        return changed

    def navigator(self, navigator):
        """NavigatorState field values of ``navigator`` (one of ``NAVIGATORS``)."""
        buttons, lights, wheel = _navigator_io(navigator)
        return {'button_names': list(NAVIGATOR_BUTTONS), 'buttons': [self.digital[b] for b in buttons],
                'wheel': int(self.analog[wheel]), 'light_names': list(NAVIGATOR_LIGHTS),
                'lights': [self.digital[light] for light in lights]}

    @staticmethod
    def navigators_of(names):
        """The navigators whose state depends on any of ``names``."""
        return [navigator for navigator in NAVIGATORS
                if any(name in names for name in _navigator_io(navigator)[0] + _navigator_io(navigator)[1]
                       + [_navigator_io(navigator)[2]])]
