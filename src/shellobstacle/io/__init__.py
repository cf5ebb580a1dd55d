"""What a run writes: result folders and versions (:mod:`.folders`), a solve's summary
(:mod:`.summary`), ParaView files (:mod:`.paraview`) and a sweep's step records
(:mod:`.checkpoint`)."""
