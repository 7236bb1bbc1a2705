from robobpp.cli import main

main()
