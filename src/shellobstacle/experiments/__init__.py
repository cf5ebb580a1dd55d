"""The paper's numerical experiments (docs/model.md §7) and our extra studies."""
