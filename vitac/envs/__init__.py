"""Insertion task on MuJoCo + dm_control composer, with gymnasium adapters."""
