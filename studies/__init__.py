"""Analysis of the perception studies: Scheffé's paired comparison (Nakaya's modification) and
paired tests of task times."""
