"""Assets that ship with the app: shaders, fonts, and the code that generates the demo scene and painting."""
