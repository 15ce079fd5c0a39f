"""Recordings: reading bags (ours and other drivers') safely, and the import mappings that
turn another vehicle's topics, units and axes into this stack's contract messages."""
