"""After a solve: norms (:mod:`.norms`), contact (:mod:`.contact`), cross-sections
(:mod:`.sections`) and figures (:mod:`.plotting`)."""
