"""The signed-in part of the web pages: sign-in sessions, CSRF, participant and operator pages.

``robobpp.server.pages`` holds the public pages; this package adds what needs to know who is looking.
Every action here calls the JSON API's own handler functions, so a form and an API call can never
disagree about quotas, URL checks or ownership.
"""
