"""Where tests imported ``wait_for`` from before tests/harness/ gathered the helpers; still importable
from here."""

from tests.harness.polling import wait_for as wait_for
