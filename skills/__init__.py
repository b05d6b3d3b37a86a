"""Skill families. Every skill implements :class:`hrtc.skill.Skill`; one module per family."""
