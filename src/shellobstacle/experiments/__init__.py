"""The paper's numerical experiments (MODEL.md §7) and our extra studies."""
