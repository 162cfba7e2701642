MODULE TestbedTask_L
  ! Task T_ROB_L (the left arm) of the testbed: its data for TestbedMotion and its
  ! entry routine. Load into task T_ROB_L only, with TestbedMotion.mod next to it.
  !
  ! The file this task reads, on the RAM disk: fixed per task, the name the driver
  ! uploads to (drivers/yumi/yumi_controller.py, program_file). The other arm's task
  ! reads its own file, so the two programs never share one.
  CONST string tb_name := "testbed_T_ROB_L.bin";
  ! The pusher. tframe is overwritten from every program's header (the calibration
  ! file's tool_z_mm); the load is the pusher's own: WEIGH IT on day one and set mass
  ! (kg) and the centre of gravity (mm, tool0 frame) here before the first motion.
  TASK PERS tooldata tool_pusher := [TRUE,[[0,0,100],[1,0,0,0]],[0.1,[0,0,50],[1,0,0,0],0,0,0]];
  ! The table top in this arm's base frame (mm): no MoveJ/MoveL target below it.
  CONST num tb_floor_z := 0;

  PROC main()
    tb_run;
  ENDPROC
ENDMODULE
