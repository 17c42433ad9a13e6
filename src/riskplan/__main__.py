from riskplan.cli import main

main()
