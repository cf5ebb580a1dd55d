"""After a solve: the points where the constraint acts (:mod:`.points`), norms (:mod:`.norms`),
contact (:mod:`.contact`), its sides and the obstacle's resolution (:mod:`.sides`,
:mod:`.resolution`), validity (:mod:`.validity`), cross-sections (:mod:`.sections`) and figures
(:mod:`.plotting`)."""
