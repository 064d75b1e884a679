"""Fast parsing of large JSON documents (plans of several MB) with orjson, with json.loads's results.

Only for *reading*. The bytes a plan's hash covers are always written by
``json.dumps`` in the contract's canonical form (:func:`schemas.plan.canonical_json`):
orjson writes some floats differently, so it never produces hashed bytes. Parsing
is exact both ways (every float reads back to the same double), so a plan parsed
here and written canonically again hashes as the stored text does.

orjson refuses what json.loads accepts in a few corners (NaN and Infinity
literals, integers beyond 64 bits, lone surrogates); such input goes to json.loads,
so the result, or the error, is always json.loads's own.

A large document is parsed with the cyclic garbage collector paused, and its
containers then go straight to the collector's oldest generation (``gc.freeze()``
then ``gc.unfreeze()``): a 60 s plan makes some 60,000 lists and dicts, which would
otherwise be traversed by the young generations' collections and set off a full
collection, during the parse or right after it (together more than the parse
itself). A parse cannot create a reference cycle, so nothing is lost by not
looking for one; the oldest generation is still collected as usual.
"""

from __future__ import annotations

import gc
import json
from contextlib import contextmanager
from typing import Any, Callable, Iterator

import orjson

#: Documents from this size on are parsed with the collector paused.
PAUSE_GC_FROM_BYTES = 256 * 1024


@contextmanager
def collector_paused(size: int) -> Iterator[None]:
    paused = size >= PAUSE_GC_FROM_BYTES and gc.isenabled()
    if paused:
        gc.disable()
    try:
        yield
    finally:
        if paused:
            gc.freeze()  # every tracked object to the permanent generation ...
            gc.unfreeze()  # ... and back into the oldest one, untraversed
            gc.enable()


def loads(data: bytes | bytearray | memoryview | str, *, parse_constant: Callable[[str], Any] | None = None) -> Any:
    """``json.loads(data, parse_constant=parse_constant)``, parsed by orjson when it can."""
    with collector_paused(len(data)):
        try:
            return orjson.loads(data)
        except orjson.JSONDecodeError:
            if isinstance(data, memoryview):
                data = data.tobytes()
            return json.loads(data, parse_constant=parse_constant)
