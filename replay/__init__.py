"""simreel.replay"""
