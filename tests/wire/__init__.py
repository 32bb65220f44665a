"""What goes on the wire: the generated messages' vocabulary, the fast codec, the code generator.

Moved here from the flat tests/ by retest.py (issue 26).
"""
