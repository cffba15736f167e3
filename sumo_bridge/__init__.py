"""sumo_bridge"""
