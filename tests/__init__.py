"""antalate test suite."""
