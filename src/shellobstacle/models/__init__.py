"""The shell models' forms: membrane, Koiter (C⁰-IP and hybrid bending), one compiled problem."""
