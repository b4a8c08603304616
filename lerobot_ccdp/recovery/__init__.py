"""The method's recovery side: eq. (4)'s composition, failure features and memory, outcomes, synthesis
(eq. 5-7)."""
