"""Newton's method on the penalized problem (docs/model.md §5–6): the energy at an iterate
(:mod:`.system`), the exact line search, the continuation in κ, nested iteration on the mesh's
levels, the normal relaxation of the membrane, and the first active set from a coarse grid."""
