"""One module per exercise of ``docs/exercises.md``; ``solve()`` runs the worked solution and checks it."""
