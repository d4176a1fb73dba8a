"""Parameters: a YAML mapping -> a validated dataclass, every error naming its key.

One helper for every parameter set of the project (vision, pick task, robot session, fake scene)::

    @dataclass
    class GainConfig(Parameters):
        gain: float = 1.0                   # checked: a finite number (an int is taken as a float)
        steps: int = 10                     # checked: an integer, not a bool
        colours: List[str] = field(default_factory=list)

        def validate(self):                 # optional: the rules between and within values
            self.require(self.gain > 0, 'gain', 'must be positive')

    GainConfig.from_dict({'gain': 2})       -> GainConfig(gain=2.0, steps=10, colours=[])
    GainConfig.from_dict({'gian': 2})       -> ParameterError "gian: unknown key (known: [...])"
    GainConfig.from_yaml('gains.yaml')      -> errors start with the file's path

Checked from the field's annotation: ``bool``, ``int``, ``float``, ``str``, ``Optional[X]`` (None allowed),
``List[X]`` / ``Tuple[X, ...]`` (a YAML list; elements checked), ``Tuple[X, Y]`` (a list of exactly that
many), ``dict``, and nested ``Parameters`` dataclasses (built from a nested mapping, errors named
``section.key``, ``items[2].key``). Other annotations (``Union[A, B]``, ``object``) pass unchecked. A field
without a default is required.
"""
import dataclasses
import math
import typing

import yaml

_NOUNS = {float: 'numbers', int: 'integers', str: 'strings', bool: 'true or false values'}
_ATTRIBUTE = object()       # Parameters.require: the value is the attribute named by the key


def join_key(where, key):
    """The path of ``key`` inside the set found at ``where``: ``a.b``, ``a[0]``, or either one if the other is ''."""
    if not where or not key:
        return where or key
    return where + key if key.startswith('[') else where + '.' + key


class ParameterError(ValueError):
    """A bad parameter: ``key`` its path (``subpixel.passes``, ``objects[1].side``; '' for the set itself) and
    ``problem`` what is wrong; the message is ``key: problem`` (``subpixel.passes: must be an integer (got 1.5)``)."""

    def __init__(self, key, problem):
        super().__init__('%s: %s' % (key, problem) if key else problem)
        self.key, self.problem = key, problem

    def within(self, where):
        """The same error (same class), its key seen from the set at ``where`` that holds this one."""
        return type(self)(join_key(where, self.key), self.problem)


def _type_error(key, what, value):
    return ParameterError(key, 'must be %s (got %r)' % (what, value))


def _convert(annotation, value, key):
    """``value`` checked (and converted, int -> float) against ``annotation``; ParameterError naming ``key``."""
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin is typing.Union:
        if value is None and type(None) in args:
            return None
        others = [a for a in args if a is not type(None)]
        return _convert(others[0], value, key) if len(others) == 1 else value
    if annotation is bool:
        if not isinstance(value, bool):
            raise _type_error(key, 'true or false', value)
        return value
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                (isinstance(value, float) and not value.is_integer()):
            raise _type_error(key, 'an integer', value)
        return int(value)
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise _type_error(key, 'a number', value)
        return float(value)
    if annotation is str:
        if not isinstance(value, str):
            raise _type_error(key, 'a string', value)
        return value
    if origin in (list, tuple) or annotation in (list, tuple):
        return _convert_sequence(origin or annotation, args, value, key)
    if origin is dict or annotation is dict:
        if not isinstance(value, dict):
            raise _type_error(key, 'a mapping', value)
        if len(args) == 2:
            return {_convert(args[0], k, key): _convert(args[1], v, join_key(key, str(k))) for k, v in value.items()}
        return value
    if isinstance(annotation, type) and issubclass(annotation, Parameters):
        if isinstance(value, annotation):
            return value
        return from_mapping(annotation, value, key)
    return value


def _convert_sequence(kind, args, value, key):
    """A list or tuple (``kind``) of the YAML list ``value``'s elements, each checked; ``Tuple[X, Y]``: exactly 2."""
    fixed = kind is tuple and args and args[-1] is not Ellipsis
    if fixed and not (isinstance(value, (list, tuple)) and len(value) == len(args)):
        noun = _NOUNS.get(args[0], 'values') if len(set(args)) == 1 else 'values'
        raise _type_error(key, 'a list of %d %s' % (len(args), noun), value)
    if not isinstance(value, (list, tuple)):
        raise _type_error(key, 'a list', value)
    elements = args if fixed else [args[0] if args else typing.Any] * len(value)
    items = [_convert(element, v, '%s[%d]' % (key, i)) for i, (element, v) in enumerate(zip(elements, value))]
    return tuple(items) if kind is tuple else items


def from_mapping(cls, values, where=''):
    """``cls(**values)`` with unknown and missing keys refused and each value checked against its field's
    annotation, then ``validate()``; every problem a ParameterError whose key starts with ``where``."""
    if not isinstance(values, dict):
        raise _type_error(where or cls.__name__, 'a mapping', values)
    hints = typing.get_type_hints(cls)
    fields = [f for f in dataclasses.fields(cls) if f.init]
    known = [f.name for f in fields]
    unknown = [key for key in values if key not in known]
    if unknown:
        raise ParameterError(join_key(where, str(unknown[0])), 'unknown key (known: %s)' % known)
    missing = [f.name for f in fields if f.name not in values
               and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
    if missing:
        raise ParameterError(join_key(where, missing[0]), 'missing')
    kwargs = {name: _convert(hints.get(name, typing.Any), value, join_key(where, name))
              for name, value in values.items()}
    try:
        instance = cls(**kwargs)
        instance.validate()
    except ParameterError as error:
        raise error.within(where) from None
    return instance


def load_mapping(path):
    """The mapping a YAML file holds (an empty file is an empty mapping); ParameterError naming ``path`` otherwise."""
    with open(path) as f:
        values = yaml.safe_load(f)
    values = {} if values is None else values
    if not isinstance(values, dict):
        raise ParameterError(str(path), 'must hold a mapping of parameters')
    return values


class Parameters:
    """Mix-in of a parameter dataclass: ``from_dict``, ``from_yaml``, ``validate`` (override), ``require``."""

    @classmethod
    def from_dict(cls, values, where=''):
        """The parameters of the mapping ``values`` (see ``from_mapping``); error keys start with ``where``."""
        return from_mapping(cls, values, where)

    @classmethod
    def from_yaml(cls, path):
        """``from_dict`` of the file's mapping; the error's message prefixed with ``path`` (same class)."""
        values = load_mapping(path)
        try:
            return cls.from_dict(values)
        except ParameterError as error:
            raise type(error)(str(path), str(error)) from None

    def validate(self):
        """Rules between and within values (the types are already checked): raise via ``require`` (or raise
        a ParameterError whose key is relative to this set)."""

    def require(self, condition, key, what, value=_ATTRIBUTE):
        """ParameterError ``key: what (got value)`` unless ``condition``; ``value`` defaults to attribute ``key``."""
        if not condition:
            raise ParameterError(key, '%s (got %r)' % (what, getattr(self, key) if value is _ATTRIBUTE else value))

    def require_positive(self, *keys):
        """Each of ``keys`` (each element of a list or tuple, named ``key[i]``) a finite number > 0; None passes."""
        self._require_numbers(keys, lambda value: value > 0, 'must be a positive number')

    def require_non_negative(self, *keys):
        """Each of ``keys`` (each element of a list or tuple, named ``key[i]``) a finite number >= 0; None passes."""
        self._require_numbers(keys, lambda value: value >= 0, 'must be a non-negative number')

    def _require_numbers(self, keys, test, what):
        for key in keys:
            value = getattr(self, key)
            if value is None:
                continue
            items = ([('%s[%d]' % (key, i), v) for i, v in enumerate(value)] if isinstance(value, (list, tuple))
                     else [(key, value)])
            for name, v in items:
                self.require(isinstance(v, (int, float)) and math.isfinite(v) and test(v), name, what, v)

    def as_dict(self):
        return dataclasses.asdict(self)
