"""Typed reading of spec values: each mistake is a SpecError naming the spec file, the key path
(``grid.avatars[1].betas``) and what was expected, in the style of flsh's scene files."""
import json
import re
from pathlib import Path

from .errors import SpecError

_NAME = re.compile(r"^[A-Za-z0-9_-]{1,64}$")


def describe(value):
    """A JSON value in a few words, for messages: 'a string ("x")', 'a number (3)', 'a list'."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return f"a number ({value!r})"
    if isinstance(value, str):
        return f'a string ("{value}")' if len(value) <= 60 else "a string"
    if isinstance(value, list):
        return f"a list of {len(value)}"
    return "an object"


def child(key, part):
    """The key path of a member (a str) or an item (an int) of the value at `key`."""
    if isinstance(part, int):
        return f"{key}[{part}]"
    return f"{key}.{part}" if key else part


def read_json(path):
    """The JSON value of the spec file at `path` (SpecError if missing or malformed)."""
    path = Path(path)
    if not path.is_file():
        raise SpecError(path, "", "spec file not found" if not path.exists() else "not a file")

    def no_constants(name):
        raise ValueError(f"{name} is not JSON")

    try:
        return json.loads(path.read_text(encoding="utf-8"), parse_constant=no_constants)
    except json.JSONDecodeError as e:
        raise SpecError(path, "", f"malformed JSON at line {e.lineno}, column {e.colno}: {e.msg}")
    except (ValueError, UnicodeDecodeError) as e:
        raise SpecError(path, "", f"malformed JSON: {e}")


class Reader:
    """Checks the values of one spec file; every failure names `source` and the key path."""

    def __init__(self, source):
        self.source = str(source)

    def fail(self, key, message):
        raise SpecError(self.source, key, message)

    def object(self, value, key, known):
        """A JSON object whose keys are all in `known`."""
        if not isinstance(value, dict):
            self.fail(key, f"expected an object, got {describe(value)}")
        for name in value:
            if name not in known:
                self.fail(child(key, name), f"unknown key (known: {', '.join(known)})")
        return value

    def list(self, value, key, min_items=0):
        if not isinstance(value, list):
            self.fail(key, f"expected a list, got {describe(value)}")
        if len(value) < min_items:
            self.fail(key, f"expected at least {min_items} item(s), got {len(value)}")
        return value

    def string(self, value, key):
        if not isinstance(value, str) or not value:
            self.fail(key, f"expected a non-empty string, got {describe(value)}")
        return value

    def boolean(self, value, key):
        if not isinstance(value, bool):
            self.fail(key, f"expected true or false, got {describe(value)}")
        return value

    def integer(self, value, key, minimum=None, maximum=None):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(key, f"expected an integer, got {describe(value)}")
        if (minimum is not None and value < minimum) or (maximum is not None and value > maximum):
            bounds = (f"{minimum} <= value <= {maximum}" if maximum is not None
                      else f"value >= {minimum}")
            self.fail(key, f"expected {bounds}, got {value}")
        return value

    def number(self, value, key, positive=False):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(key, f"expected a number, got {describe(value)}")
        if positive and not value > 0:
            self.fail(key, f"expected 0 < value, got {value}")
        return float(value)

    def name(self, value, key):
        """A name that can be an avatar name and part of a job id: 1-64 letters, digits, _ or -."""
        if not isinstance(value, str) or not _NAME.match(value):
            self.fail(key, "expected a name of 1-64 letters, digits, '_' or '-', got "
                           f"{describe(value)}")
        return value

    def choice(self, value, key, choices):
        if value not in choices:
            self.fail(key, f"expected one of {', '.join(map(json.dumps, choices))}, got "
                           f"{describe(value)}")
        return value
