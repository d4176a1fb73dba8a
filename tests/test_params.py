"""params: mapping -> validated dataclass, the checks each annotation gets, and errors naming their key path."""
import re
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple, Union

import pytest

from baxter_pnp.params import ParameterError, Parameters, join_key, load_mapping


@dataclass(frozen=True)
class Window(Parameters):
    at: float
    duration: float = 1.0

    def validate(self):
        self.require_positive('duration')


@dataclass
class Example(Parameters):
    gain: float = 1.0
    steps: int = 10
    enabled: bool = True
    name: str = 'x'
    limit: Optional[float] = None
    names: List[str] = field(default_factory=list)
    point: Tuple[float, float] = (0.0, 0.0)
    sizes: Tuple[float, ...] = ()
    table: dict = field(default_factory=dict)
    either: Union[str, Dict[str, float]] = 'a'
    window: Window = field(default_factory=lambda: Window(0.0))
    windows: Tuple[Window, ...] = ()
    late: Optional[Window] = None

    def validate(self):
        self.require(self.gain < 100, 'gain', 'must be below 100')
        self.require_non_negative('limit', 'sizes')


def error_of(values):
    with pytest.raises(ParameterError) as error:
        Example.from_dict(values)
    return str(error.value)


def test_values_are_checked_converted_and_nested():
    e = Example.from_dict({'gain': 2, 'steps': 3.0, 'point': [1, 2], 'sizes': [1, 2.5], 'names': ['a'],
                           'window': {'at': 1}, 'windows': [{'at': 0, 'duration': 2}], 'late': None,
                           'either': {'q': 1}})
    assert (e.gain, e.steps, e.point, e.sizes, e.names) == (2.0, 3, (1.0, 2.0), (1.0, 2.5), ['a'])
    assert type(e.gain) is float and type(e.steps) is int and type(e.point[0]) is float
    assert e.window == Window(1.0) and e.windows == (Window(0.0, 2.0),) and e.late is None
    assert e.either == {'q': 1}                            # a union of two types passes unchecked
    assert Example.from_dict({}) == Example()
    assert Example.from_dict({'window': Window(3.0)}).window == Window(3.0)    # an instance is taken as it is


@pytest.mark.parametrize('values, message', [
    ({'gian': 2}, "gian: unknown key (known: ['gain', "),
    ({'gain': 'high'}, "gain: must be a number (got 'high')"),
    ({'gain': True}, 'gain: must be a number (got True)'),
    ({'gain': float('inf')}, 'gain: must be a number (got inf)'),
    ({'gain': float('nan')}, 'gain: must be a number (got nan)'),
    ({'gain': 200}, 'gain: must be below 100 (got 200.0)'),
    ({'steps': 1.5}, 'steps: must be an integer (got 1.5)'),
    ({'steps': float('inf')}, 'steps: must be an integer (got inf)'),
    ({'steps': False}, 'steps: must be an integer (got False)'),
    ({'enabled': 'yes'}, "enabled: must be true or false (got 'yes')"),
    ({'name': 3}, 'name: must be a string (got 3)'),
    ({'limit': -1}, 'limit: must be a non-negative number (got -1.0)'),
    ({'names': 'a'}, "names: must be a list (got 'a')"),
    ({'names': ['a', 2]}, 'names[1]: must be a string (got 2)'),
    ({'point': [1.0]}, 'point: must be a list of 2 numbers (got [1.0])'),
    ({'point': [1.0, None]}, 'point[1]: must be a number (got None)'),
    ({'sizes': [1.0, -2.0]}, 'sizes[1]: must be a non-negative number (got -2.0)'),
    ({'table': [1]}, 'table: must be a mapping (got [1])'),
    ({'window': 3}, 'window: must be a mapping (got 3)'),
    ({'window': {}}, 'window.at: missing'),
    ({'window': {'at': 0, 'duration': 0}}, 'window.duration: must be a positive number (got 0.0)'),
    ({'window': {'at': 0, 'lenght': 1}}, 'window.lenght: unknown key'),
    ({'windows': [{'at': 0}, {'at': 'x'}]}, "windows[1].at: must be a number (got 'x')"),
    ({'late': {'at': 1, 'duration': -1}}, 'late.duration: must be a positive number'),
])
def test_errors_start_with_the_key_path(values, message):
    assert error_of(values).startswith(message)


def test_top_level_must_be_a_mapping_and_where_prefixes_every_key():
    with pytest.raises(ParameterError, match=r'^Example: must be a mapping \(got \[1\]\)$'):
        Example.from_dict([1])
    with pytest.raises(ParameterError, match=r'^task\.window\.duration: must be a positive number'):
        Example.from_dict({'window': {'at': 0, 'duration': -1}}, 'task')
    with pytest.raises(ParameterError, match=r'^items\[2\]\.duration: must be a positive number'):
        Window.from_dict({'at': 0, 'duration': -1}, 'items[2]')


def test_error_keys_join_and_keep_their_class():
    assert [join_key('a', 'b'), join_key('a', '[0]'), join_key('', 'b'), join_key('a', '')] == ['a.b', 'a[0]', 'b', 'a']

    class OwnError(ParameterError):
        pass
    error = OwnError('x[1]', 'bad').within('set')
    assert type(error) is OwnError and (error.key, error.problem, str(error)) == ('set.x[1]', 'bad', 'set.x[1]: bad')
    assert str(ParameterError('', 'whole set bad').within('box')) == 'box: whole set bad'


def test_from_yaml_prefixes_the_path(tmp_path):
    path = tmp_path / 'example.yaml'
    path.write_text('gain: 3\nwindow: {at: 2}\n')
    assert Example.from_yaml(str(path)) == Example(gain=3.0, window=Window(2.0))
    path.write_text('')
    assert Example.from_yaml(str(path)) == Example()                  # an empty file: the defaults
    path.write_text('window: {at: 2, duration: 0}\n')
    with pytest.raises(ParameterError, match='^' + re.escape(f'{path}: window.duration: must be a positive number')):
        Example.from_yaml(str(path))
    path.write_text('- 1\n- 2\n')
    with pytest.raises(ParameterError, match='^' + re.escape(f'{path}: must hold a mapping')):
        load_mapping(str(path))


def test_require_names_an_explicit_value():
    window = Window(0.0)
    with pytest.raises(ParameterError, match=r'^at\[0\]: too small \(got -3\)$'):
        window.require(False, 'at[0]', 'too small', -3)
    window.require(True, 'nothing', 'never raised')
