"""hera.bench"""
