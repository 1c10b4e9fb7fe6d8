"""simreel.viewers"""
