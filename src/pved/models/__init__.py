"""pved.models"""
