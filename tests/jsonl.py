"""Where tests imported ``JsonLinesProcess`` from before tests/harness/ gathered the helpers; still
importable from here."""

from tests.harness.jsonl import JsonLinesProcess as JsonLinesProcess
