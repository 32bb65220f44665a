"""The helpers every test leans on, in one place: private network namespaces (``netns``), child
processes (``process``), polling with a deadline (``polling``), JSON-lines peers (``jsonl``), the event
timeline of a child that reports JSON lines (``timeline``) and an agent's config and processes
(``agents``).

The modules they came from (``tests.netns``, ``tests.polling``, ``tests.jsonl``,
``tests.agent_harness``) still import the same names, so tests written against them keep working; new
tests import from here.
"""
