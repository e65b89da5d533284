"""pved.envs"""
