"""Fuzzing helpers for fuse4d's readers (see ``tests/test_fuzz_readers.py``).

:mod:`.contract` checks the reader contract (a fuse4d error or a valid result; never another
exception, a hang or a memory blow-up); :mod:`.mutate` holds hypothesis strategies that damage
files; :mod:`.targets` lists one :class:`~.targets.FuzzTarget` per reader. A new reader (e.g.
the sensor readers) is fuzzed by appending one entry to :data:`.targets.TARGETS`.
"""
