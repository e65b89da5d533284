"""pved.analysis"""
