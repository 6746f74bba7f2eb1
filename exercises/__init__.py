"""Worked solutions of the exercises in ``docs/exercises.md``.

Not part of the installed package: each solution is a small module with a ``solve()`` that computes its
answer with mpmref, checks it against the prediction the exercise asks for, and returns the numbers.
``tests/test_exercises.py`` runs every one.
"""
