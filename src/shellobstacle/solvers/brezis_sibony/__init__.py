"""The Brezis–Sibony iteration for the penalized problem (docs/model.md §6, the paper's (38))
and the record of what a run of it did."""
