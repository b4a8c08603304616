"""Recovery data synthesis (eq. 5-7): the lerobot-ccdp-synthesize command over a demonstration dataset and a
base checkpoint, and the recovery pairs it keeps. It sits above the policy: it imports the policy, never the
reverse."""
