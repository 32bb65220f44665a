"""The helpers every test leans on, in one place: private network namespaces (``netns``), child
processes (``process``), polling with a deadline (``polling``) and JSON-lines peers (``jsonl``).

The modules they came from (``tests.netns``, ``tests.polling``, ``tests.jsonl``) still import the same
names, so tests written against them keep working; new tests import from here.
"""
