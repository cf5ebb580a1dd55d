"""The shell models' forms: membrane, Koiter (C⁰-IP and hybrid bending), one compiled problem
(:mod:`.problem`) and the check of a curved obstacle's linearization point (:mod:`.singular`)."""
